"""conflate: run every trained model and the MLN classifier on all frames, combine them (eq. 16) and,
on request, decode each over the frame chain with the MLN's temporal factors.

Conflation of two class distributions, per class k (eq. 16):
    P_C(k) = P_L(k)·P_K(k) / (P_L(k)·P_K(k) + (1 − P_L(k))·(1 − P_K(k)))
and the prediction is argmax_k P_C(k). The stored conflated values are eq. 16 as it stands, not
renormalised to sum to 1 (the argmax is the same either way).

Methods: lstm, priorlayer (the networks), mln (the MLN classifier alone), conflation (lstm + MLN)
and combined (priorlayer + MLN); with ``--decode filter`` or ``viterbi`` also METHOD+filter (online
forward filtering) and METHOD+viterbi (offline: the most probable path, forward-backward marginals).
A method whose inputs are absent is left out with a note. The core (:func:`predict`) works on the
workdir's arrays (stages/choosing/workdir_inputs.py); fusion and decoding are stages/recognition/recognizer.py's, the
network factor's weight stages/choosing/network_weight.py's.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput, MissingArtifact, check_choice
from mlnseq.catalog.decoders import DEFAULT_LAGS, Decoder, decodings, parse_lags
from mlnseq.catalog.methods import (METHODS, MLN_MODES, NETWORKS, MLNMode, decoded_name, decoders_named, member,
                                    network_of)
from mlnseq.catalog.notes import CHAIN_RESTARTED, Note
from mlnseq.catalog.parts import Part
from mlnseq.mln import chain
from mlnseq.mln.blas import one_thread
from mlnseq.fusion import decoding as decoders
from mlnseq.choosing.cross_validation import CrossValidated, cross_validate
from mlnseq.choosing.latency import Candidate, candidates, ranked
from mlnseq.choosing.network_weight import WeightChoice, WeightDecision
from mlnseq.fusion.fuse import chain_of, fuse, restart_note
from mlnseq.choosing.workdir_inputs import WorkdirInputs, read_workdir


@dataclass(frozen=True)
class ConflateOptions:
    """Options of `mlnseq conflate`."""

    mln_mode: MLNMode = MLNMode.PAPER
    decode: tuple[str, ...] = ("none",)  # decoders (stages/catalog/decoders.py): none, filter, viterbi, smooth, ...
    network_weight: float | None = None  # decoded methods' network factor: None = learned (folds) or chosen
    lags: tuple[int, ...] = DEFAULT_LAGS  # frames: each lagged decoder (smooth, lagviterbi) at each

    def __post_init__(self) -> None:
        object.__setattr__(self, "mln_mode", member(MLNMode, self.mln_mode))

    def validate(self) -> None:
        check_choice("mln-mode", self.mln_mode, MLN_MODES)
        for kind in self.decode:
            check_choice("decode", kind, [d.value for d in Decoder], "all, or a comma list such as none,viterbi")
        if self.network_weight is not None and not self.network_weight > 0:
            raise BadInput(f"--network-weight must be positive (or auto), got {self.network_weight}")
        if not self.lags or min(self.lags) < 0:
            raise BadInput(f"--lags {','.join(map(str, self.lags))}: give one or more lags of at least 0 frames")

    @property
    def decodes(self) -> tuple[str, ...]:
        """The decodings asked for (lagged decoders at each lag: ``smooth@5``), undecoded first; undecoded methods
        are always predicted."""
        asked = tuple(Decoder(kind) for kind in self.decode)
        return ("none", *dict.fromkeys(d.name for d in decodings(asked, tuple(self.lags))))


LAGS_TEXT = ",".join(map(str, DEFAULT_LAGS))  # --lags as written by default


def options_from(mln_mode: str, decode: str, lags: str = LAGS_TEXT, network_weight: str = "auto") -> ConflateOptions:
    """The options as the command line writes them: ``--decode`` (a decoder as names print it, ``smooth-legal@5``,
    brings its lag; then ``--lags`` must not name others), ``--lags``, ``--network-weight``."""
    decoders, named_lags = decoders_named(parse_decode(decode))
    if named_lags and lags != LAGS_TEXT:
        raise BadInput(f"--decode {decode} names its lags; --lags {lags} names others: give the lags once")
    return ConflateOptions(mln_mode=mln_mode, decode=decoders, network_weight=parse_network_weight(network_weight),
                           lags=named_lags or parse_lags(lags))


def ranking(path: Path) -> tuple[dict[str, Any] | None, list[Candidate]]:
    """A predictions file's cross-validation record (None without fold networks) and its candidates, best first by
    the criterion ``export --method auto`` chooses on."""
    cross = artifacts.read_metadata(path).get("cross_validation")
    if not cross:
        return None, []
    return cross, ranked(candidates(cross["figures"], cross.get("fold_frame_accuracy")))


def parse_decode(text: str) -> tuple[str, ...]:
    """``--decode`` as written: one name, ``all``, or a comma list."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    return tuple(d.value for d in Decoder) if names == ("all",) else names


def parse_network_weight(text: str) -> float | None:
    """``--network-weight`` as written: auto (None: chosen on validation) or a number."""
    if text == "auto":
        return None
    try:
        return float(text)
    except ValueError:
        raise BadInput(f"--network-weight must be auto or a number, got {text!r}") from None


def predictions_table(keys: pl.DataFrame, probabilities: dict[str, np.ndarray],
                      predicted: dict[str, np.ndarray]) -> pl.DataFrame:
    """Keys, then per method its predicted class (int16) and its class probabilities (float32)."""
    columns = [keys]
    for method, classes in predicted.items():  # lagged decoders: classes only (their probabilities are not stored)
        probs = probabilities.get(method)
        columns.append(pl.DataFrame(
            [pl.Series(artifacts.pred_column(method), classes, dtype=pl.Int16)]
            + ([] if probs is None else [pl.Series(name, probs[:, k], dtype=pl.Float32)
                                         for k, name in enumerate(artifacts.prob_columns(method, probs.shape[1]))])
        ))
    return pl.concat(columns, how="horizontal")


@dataclass
class WorkdirPredictions:
    """Every method's class probabilities over a workdir's frames, with what was chosen and said."""

    probabilities: dict[str, np.ndarray] = field(default_factory=dict)  # method name (decoded too) -> [n, C]
    predicted: dict[str, np.ndarray] = field(default_factory=dict)  # method name -> [n] class index
    modes: dict[str, str] = field(default_factory=dict)  # method name -> segment | stream | frame
    choices: dict[str, WeightChoice] = field(default_factory=dict)  # decoded network methods -> network weight
    validation: dict[str, float] = field(default_factory=dict)  # method -> frame accuracy on the validation part
    notes: list[Note] = field(default_factory=list)
    cross_validated: CrossValidated | None = None  # with fold networks: every method's cross-validated figures
    restarts: dict[str, list[tuple[Any, int]]] = field(default_factory=dict)  # decoded method -> (episode, frame)
    forbidden: dict[str, int] = field(default_factory=dict)  # decoded method -> forbidden transitions on test
    start: list[float] | None = None  # the chains' start distribution (log), from the training split's episodes
    hard_rules: bool = False  # the chain's transition factors forbid some transition outright (-inf)


def predict(inputs: WorkdirInputs, mln_mode: str, decodes: Sequence[str] = ("none",),
            methods: Sequence[str] = METHODS, network_weight_option: float | None = None) -> WorkdirPredictions:
    """Fuse and decode the workdir's networks and MLN (pure, on the arrays ``inputs`` holds).

    A method whose inputs are absent is left out. A decoded network method's network factor weight is
    ``network_weight_option`` when given, else chosen on the validation part its network held out in training
    (never on test); a network trained without one keeps the weight 1, and a note says so.
    """
    from mlnseq.mln import classifier

    data, mln_inputs = inputs.data, inputs.mln
    result = WorkdirPredictions(notes=list(inputs.notes))
    p_mln = None
    if mln_inputs is not None:
        p_mln = np.exp(classifier.class_log_probs(mln_inputs.scores, mln_mode, inputs.paper_floor))
    networks = inputs.networks
    available = [m for m in methods if (network_of(m) is None or network_of(m) in networks)
                 and (m in NETWORKS or p_mln is not None)]
    if not available:
        raise MissingArtifact("nothing to predict with in this workdir: run `mlnseq learn-weights` "
                              "and/or `mlnseq train` first")
    for method in available:
        network = network_of(method)
        probabilities = fuse(method, None if network is None else np.exp(networks[network].log_probs), p_mln)
        result.probabilities[method], result.predicted[method] = probabilities, probabilities.argmax(1)
        result.modes[method] = "frame" if network is None else networks[network].checkpoint.mode

    validation = np.zeros(len(data.labels), dtype=bool)  # the networks hold out the same units, given the same options
    for trained in networks.values():
        validation |= trained.parts == Part.VAL
    decoding = [d for d in decodes if d != "none"]
    if decoding and mln_inputs is None:
        raise BadInput(f"--decode {','.join(decoding)} needs the MLN's factors: run `mlnseq learn-weights` first")
    with one_thread():  # one block for the dozens of network-weight fits below
        if decoding:
            _decode(inputs, decoding, available, network_weight_option, result)
        if inputs.folds is not None:
            result.cross_validated = cross_validate(inputs, mln_mode, decodes, available, network_weight_option)
    if validation.any():
        result.validation.update({name: float((predicted[validation] == data.labels[validation]).mean())
                                  for name, predicted in result.predicted.items()})
    return result


def _decode(inputs: WorkdirInputs, decoding: list[str], available: list[str], network_weight_option: float | None,
            result: WorkdirPredictions) -> None:
    from mlnseq.mln.factors import MLNFactors

    data, mln_inputs, networks = inputs.data, inputs.mln, inputs.networks
    mln = MLNFactors.from_weights(mln_inputs.weights, mln_inputs.columns, inputs.classes)
    weights = WeightDecision(inputs, mln, network_weight_option)
    result.notes += weights.notes(list(networks))
    split_parts = np.where(data.splits == Part.TEST, Part.TEST, Part.TRAIN)
    start = decoders.training_start(data.labels, data.episodes, data.splits, len(inputs.classes))
    result.start = start.tolist()
    test = data.splits == "test"
    # one chain per method and weight, decoded with every decoding that weight serves; the chains served by the same
    # decodings are decoded at once (decoders.decode_each)
    chains: dict[tuple[str, ...], list[tuple[str, chain.ChainFactors]]] = {}
    chosen: dict[tuple[str, str], WeightChoice | None] = {}
    for method in available:
        network = network_of(method)
        rows = networks[network].parts if network is not None else split_parts
        by_weight: dict[float, list[str]] = {}
        for kind in decoding:
            choice = chosen[method, kind] = weights.choice(method, kind) if network is not None else None
            by_weight.setdefault(1.0 if choice is None else choice.weight, []).append(kind)
        for weight, kinds in by_weight.items():
            factors = chain_of(method, mln, mln_inputs.evidence, chain.chain_starts(data.episodes, rows),
                               networks[network].log_probs if network is not None else None, weight, start)
            chains.setdefault(tuple(kinds), []).append((method, factors))
    decoded: dict[tuple[str, str], tuple[chain.ChainFactors, chain.Decoded]] = {}
    for kinds, group in chains.items():
        for (method, factors), outs in zip(group, decoders.decode_each([f for _, f in group], kinds)):
            decoded.update({(method, kind): (factors, out) for kind, out in zip(kinds, outs)})
    for kind in decoding:
        for method in available:
            name = decoded_name(method, kind)
            (factors, out), choice = decoded[method, kind], chosen[method, kind]
            if choice is not None and network_weight_option is None:  # a weight given by option is the option's
                result.choices[name] = choice
            result.hard_rules |= bool(np.isneginf(factors.pairwise).any())
            result.predicted[name] = out.path
            if "@" not in kind:
                result.probabilities[name] = out.probabilities
            result.forbidden[name] = decoders.forbidden_in(factors, out.path, test)
            if len(out.restarts):
                keys, names = inputs.keys[out.restarts], inputs.meta.get("episode_names") or []  # the user's ids
                result.restarts[name] = [(names[e] if 0 <= e < len(names) else e, f)
                                         for e, f in zip(keys["episode"].to_list(), keys["frame"].to_list())]
                result.notes.append(Note(CHAIN_RESTARTED, restart_note(name, result.restarts[name])))
            result.modes[name] = result.modes[method]


@dataclass(frozen=True)
class ConflateResult:
    path: Path
    methods: list[str]
    notes: list[Note]
    choices: dict[str, WeightChoice]


def run(workdir: Path, options: ConflateOptions) -> ConflateResult:
    """Read frames, models and MLN weights from ``workdir``; write ``predictions.parquet``."""
    options.validate()
    workdir = Path(workdir)
    inputs = read_workdir(workdir, NETWORKS)
    predicted = predict(inputs, options.mln_mode, options.decodes, network_weight_option=options.network_weight)
    methods = [decoded_name(m, d) for d in options.decodes for m in METHODS
               if decoded_name(m, d) in predicted.predicted]
    table = predictions_table(inputs.keys, {m: predicted.probabilities[m] for m in methods
                                            if m in predicted.probabilities},
                              {m: predicted.predicted[m] for m in methods})
    meta: dict[str, Any] = {
        "methods": methods, "modes": {m: predicted.modes[m] for m in methods}, "mln_mode": str(options.mln_mode),
        "decode": list(options.decodes), "network_weight_option": options.network_weight,
        "classes": inputs.classes, "paper_floor": str(inputs.paper_floor),
        "network_weights": {m: c.record() for m, c in predicted.choices.items()},
        "validation_frame_accuracy": {m: predicted.validation[m] for m in methods if m in predicted.validation},
        "notes": [n.text for n in predicted.notes], "note_codes": [n.code for n in predicted.notes],
        "cross_validation": None, "lags": list(options.lags), "start": predicted.start,
        "hard_rules": predicted.hard_rules,
        "forbidden_transitions": {m: predicted.forbidden[m] for m in methods if m in predicted.forbidden},
    }
    cv = predicted.cross_validated
    if cv is not None:
        meta["cross_validation"] = {"folds": inputs.folds.folds.record(),
                                    "figures": {m: cv.figures[m] for m in methods if m in cv.figures},
                                    "fold_network_weights": cv.fold_weights,
                                    "fold_frame_accuracy": {m: cv.fold_frames[m] for m in methods
                                                            if m in cv.fold_frames}}
    path = artifacts.write_table(table, workdir / artifacts.PREDICTIONS, "predictions", meta, inputs=inputs.inputs)
    return ConflateResult(path, methods, predicted.notes, predicted.choices)
