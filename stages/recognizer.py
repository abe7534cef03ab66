"""A trained model turned into class probabilities: checkpoints, standardisation, the MLN input, the
networks, fusion (eq. 16) and decoding.

`conflate` (every method over a workdir), `predict` (a model file over new recordings), `stream` (one
frame at a time) and the Python API all call this module; `train` fits and saves what it loads.
torch is imported only where a network runs, so the method names and options here stay light.
"""

from __future__ import annotations

import io
import json
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from stages import artifacts, sequences
from stages.errors import BadInput, MissingArtifact, StaleArtifact

if TYPE_CHECKING:
    import torch

    from stages.binarize import PredicateSpec
    from stages.mln.chain import ChainFactors
    from stages.mln.factors import MLNFactors
    from stages.models import SequenceClassifier, StreamingClassifier

NETWORKS = ("lstm", "priorlayer")
METHODS = ("lstm", "mln", "priorlayer", "conflation", "combined")
FUSED = {"conflation": "lstm", "combined": "priorlayer"}  # a fused method -> the network it conflates
PRIORS = ("paper", "logprob")  # the c2c input of PriorLayer: clamped MLN sums (the authors') or log-probs
MLN_MODES = ("paper", "exact")
DECODES = ("none", "filter", "viterbi")  # none: per frame; filter: online chain; viterbi: offline chain
NETWORK_WEIGHTS = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)  # the network factor's weights tried on validation
CHECKPOINT_FORMAT = 1
INFERENCE_BATCH = 256
EPSILON = 1e-7  # keeps eq. 16 defined when one side is exactly 0 and the other exactly 1


def network_of(method: str) -> str | None:
    """The network a method runs (None for the MLN alone)."""
    return FUSED.get(method, method if method in NETWORKS else None)


def decoded_name(method: str, decode: str) -> str:
    """How predictions and metrics name a method with a decoding: ``lstm``, ``lstm+filter``, ``mln+viterbi``."""
    return method if decode == "none" else f"{method}+{decode}"


def method_names() -> list[str]:
    """Every method name predictions.parquet may hold, decoded ones included."""
    return [decoded_name(m, d) for d in DECODES for m in METHODS]


def parse_method(name: str, option: str = "--method") -> tuple[str, str]:
    """(method, decode) of a name such as ``combined+viterbi``; an unknown one is a BadInput naming ``option``."""
    method, _, decode = name.partition("+")
    decode = decode or "none"
    if method not in METHODS or decode not in DECODES[1:] + (("none",) if "+" not in name else ()):
        raise BadInput(f"unknown {option} {name!r}: choose one of {', '.join(METHODS)}, "
                       f"optionally with +filter or +viterbi (e.g. combined+filter)")
    return method, decode


def set_threads() -> None:
    """Small recurrent nets run fastest on one thread (measured: 8x faster than two on this 2-core CPU)."""
    import torch

    torch.set_num_threads(1)


@dataclass(frozen=True)
class FrameData:
    """The frames a network reads: raw features, labels, episode and split (train/test) per row."""

    features: np.ndarray  # [n, F] float32, raw
    labels: np.ndarray  # [n] int64
    episodes: np.ndarray  # [n]
    splits: np.ndarray  # [n] "train" | "test"
    prior: np.ndarray | None = None  # [n, C] float32, the c2c input of PriorLayer

    @classmethod
    def from_frames(cls, frames: pl.DataFrame, prior: np.ndarray | None = None) -> FrameData:
        return cls(
            features=frames.select(artifacts.feature_columns(frames)).to_numpy().astype(np.float32),
            labels=frames["label"].to_numpy().astype(np.int64),
            episodes=frames["episode"].to_numpy(),
            splits=frames["split"].to_numpy(),
            prior=prior,
        )


# --- networks ---------------------------------------------------------------------------------------


def predict_log_probs(
    model: SequenceClassifier, spans: list[slice], features: np.ndarray, prior: np.ndarray | None,
    device: torch.device | None = None,
) -> np.ndarray:
    """Class log-probabilities of every row covered by ``spans`` (each span a fresh sequence)."""
    import torch

    device = device or torch.device("cpu")
    model.eval()
    out = np.zeros((len(features), model.config.n_classes), dtype=np.float32)
    ordered = sorted(spans, key=lambda s: s.stop - s.start)  # similar lengths share a batch
    with torch.inference_mode():
        for i in range(0, len(ordered), INFERENCE_BATCH):
            batch = ordered[i : i + INFERENCE_BATCH]
            x = sequences.pad(batch, features).to(device)
            p = None if prior is None else sequences.pad(batch, prior).to(device)
            log_probs = model(x, p)[0].cpu().numpy()
            for j, span in enumerate(batch):
                out[span] = log_probs[j, : span.stop - span.start]
    return out


@dataclass
class Checkpoint:
    """A trained network with the configuration it embeds."""

    model: SequenceClassifier
    config: dict[str, Any]

    @property
    def mode(self) -> str:
        return self.config["mode"]

    def standardise(self, features: np.ndarray) -> np.ndarray:
        mean = np.asarray(self.config["mean"], dtype=np.float32)
        std = np.asarray(self.config["std"], dtype=np.float32)
        return ((features - mean) / std).astype(np.float32)

    def streaming(self) -> StreamingClassifier:
        """A per-frame online classifier with this network and standardisation."""
        from stages.models import StreamingClassifier

        return StreamingClassifier(self.model, np.asarray(self.config["mean"]), np.asarray(self.config["std"]))


def network_probabilities(checkpoint: Checkpoint, data: FrameData) -> np.ndarray:
    """Run a trained network over every frame in its sequence mode; class probabilities [n, C]."""
    set_threads()
    spans = sequences.sequences(checkpoint.mode, data.episodes, data.splits, data.labels)
    log_probs = predict_log_probs(checkpoint.model, spans, checkpoint.standardise(data.features), data.prior)
    return np.exp(log_probs.astype(np.float64))


def save_checkpoint(path: Path, model: SequenceClassifier, config: dict[str, Any]) -> Path:
    """Write a checkpoint atomically: an interrupted save leaves the previous file as it was."""
    import torch

    with artifacts.atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:  # a file object: the archive is named 'archive', not the random temp name
            torch.save({"config": {**config, "format": CHECKPOINT_FORMAT}, "state_dict": model.state_dict()}, handle)
    return path


def load_checkpoint(workdir: Path, method: str, frames_meta: dict[str, Any] | None = None) -> Checkpoint:
    """Load ``models/<method>.pt``; refuse one made from other inputs, features or classes."""
    import torch

    from stages.models import ModelConfig, SequenceClassifier

    path = artifacts.checkpoint_path(workdir, method)
    if not path.exists():
        raise BadInput(f"{path} not found: run `mlnseq train --method {method}` first")
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
        config = saved["config"]
    except Exception as error:  # torch raises many types for a foreign or truncated file
        raise BadInput(f"{path} is not an mlnseq checkpoint ({error}); rerun `mlnseq train --method {method}`") from error
    if config.get("format") != CHECKPOINT_FORMAT:
        raise BadInput(f"{path} has checkpoint format {config.get('format')}, this mlnseq reads "
                       f"{CHECKPOINT_FORMAT}; rerun `mlnseq train --method {method}`")
    if frames_meta is not None:
        for key in ("features", "classes"):
            if list(config[key]) != list(frames_meta[key]):
                raise BadInput(f"{path} was trained on {key} {config[key]}, but {artifacts.FRAMES} has "
                               f"{frames_meta[key]}; rerun `mlnseq train --method {method}`")
    for name, digest in config["inputs"].items():
        source = workdir / name
        if source.exists() and artifacts.file_digest(source) != digest:
            raise StaleArtifact(f"{path} was trained on an older {name}; rerun `mlnseq train --method {method}`")
    model = SequenceClassifier(ModelConfig(**config["model"]))
    model.load_state_dict(saved["state_dict"])
    return Checkpoint(model.eval(), config)


# --- the MLN ----------------------------------------------------------------------------------------


def read_mln(workdir: Path, frames: pl.DataFrame) -> tuple[pl.DataFrame, pl.DataFrame, list[Path]]:
    """predicates.parquet (checked to hold the frames of frames.parquet) and weights.parquet, and their paths."""
    predicates_path, weights_path = workdir / artifacts.PREDICATES, workdir / artifacts.WEIGHTS
    predicates, _ = artifacts.read_table(predicates_path, "predicates")
    weights, _ = artifacts.read_table(weights_path, "weights")
    keys = ["episode", "frame"]
    if predicates.height != frames.height or not predicates.select(keys).equals(frames.select(keys)):
        raise StaleArtifact(f"{predicates_path} does not hold the frames of {artifacts.FRAMES}; "
                            "rerun `mlnseq binarize`")
    return predicates, weights, [predicates_path, weights_path]


def mln_class_scores(workdir: Path, frames: pl.DataFrame, n_classes: int) -> tuple[np.ndarray, list[Path]]:
    """Per-frame summed MLN formula weights per class, from predicates.parquet and weights.parquet."""
    from stages.mln import classifier

    predicates, weights, inputs = read_mln(workdir, frames)
    return classifier.class_scores(predicates, weights, n_classes), inputs


def prior_input(scores: np.ndarray, kind: str, source: str) -> np.ndarray:
    """The c2c input of PriorLayer: the MLN class weights as the authors passed them, or log-probs."""
    from stages.mln import classifier

    if kind == "paper":
        return np.asarray(classifier.paper_prior(scores, source), dtype=np.float32)
    return np.asarray(classifier.class_log_probs(scores, "exact", source), dtype=np.float32)


# --- fusion -----------------------------------------------------------------------------------------


def conflation(p_network: np.ndarray, p_mln: np.ndarray) -> np.ndarray:
    """Eq. 16 per class on [n, C] probabilities: P_L·P_K / (P_L·P_K + (1 − P_L)·(1 − P_K)).

    The values are eq. 16 as it stands, not renormalised to sum to 1 (the argmax is the same either way).
    """
    a = np.clip(np.asarray(p_network, dtype=np.float64), EPSILON, 1 - EPSILON)
    b = np.clip(np.asarray(p_mln, dtype=np.float64), EPSILON, 1 - EPSILON)
    return a * b / (a * b + (1 - a) * (1 - b))


def fuse(method: str, p_network: np.ndarray | None, p_mln: np.ndarray | None) -> np.ndarray:
    """A method's per-frame class probabilities, undecoded: the network, the MLN, or eq. 16 of the two."""
    if method == "mln":
        return p_mln
    if method in NETWORKS:
        return p_network
    return conflation(p_network, p_mln)


# --- decoding ---------------------------------------------------------------------------------------


def chain_starts(*keys: np.ndarray) -> np.ndarray:
    """True where a chain starts: the first row, and wherever any key (episode, part) changes."""
    starts = np.zeros(len(keys[0]), dtype=bool)
    for run in sequences.runs(*keys):
        starts[run.start] = True
    return starts


def chain_of(method: str, mln: MLNFactors, evidence: np.ndarray, starts: np.ndarray,
             log_p_network: np.ndarray | None, weight: float) -> ChainFactors:
    """The chain a decoded method runs: the MLN's transition factors, and per frame the MLN's factor (mln,
    conflation, combined) plus ``weight`` times the network's log-probabilities (every method but mln)."""
    factors = mln.chain(evidence, starts, per_frame=method == "mln" or method in FUSED)
    if method == "mln":
        return factors
    return replace(factors, unary=factors.unary + weight * np.asarray(log_p_network, dtype=np.float64))


def decode(kind: str, factors: ChainFactors) -> tuple[np.ndarray, np.ndarray]:
    """(class probabilities [T, C], predicted classes [T]): filter is online (each frame from the frames up
    to it); viterbi is offline (the most probable path, with forward-backward marginals as probabilities)."""
    from stages.mln import chain

    if kind == "filter":
        probabilities = np.exp(chain.filtered(factors))
        return probabilities, probabilities.argmax(1)
    return np.exp(chain.smoothed(factors)), chain.viterbi(factors)


@dataclass(frozen=True)
class WeightChoice:
    """The network factor's weight of a decoded method, and the validation frame accuracy it gave."""

    weight: float
    accuracy: float | None  # None: no validation part, the weight is fixed at 1
    tried: dict[float, float]


def choose_network_weight(method: str, kind: str, mln: MLNFactors, evidence: np.ndarray, starts: np.ndarray,
                          log_p_network: np.ndarray, labels: np.ndarray, validation: np.ndarray) -> WeightChoice:
    """The weight in NETWORK_WEIGHTS with the best frame accuracy on the ``validation`` rows (ties: the one
    nearest 1); with no validation row the weight is 1. Test rows are never passed here."""
    if not validation.any():
        return WeightChoice(1.0, None, {})
    rows = np.flatnonzero(validation)
    starts = starts[rows] | np.r_[True, np.diff(rows) > 1]  # a chain also starts where validation resumes
    tried = {}
    for weight in NETWORK_WEIGHTS:
        factors = chain_of(method, mln, evidence[validation], starts, log_p_network[validation], weight)
        tried[weight] = float((decode(kind, factors)[1] == labels[validation]).mean())
    best = max(tried, key=lambda w: (tried[w], -abs(np.log(w))))
    return WeightChoice(best, tried[best], tried)


# --- every method over a workdir (conflate, export) --------------------------------------------------


def parts_of(config: dict[str, Any], splits: np.ndarray) -> np.ndarray:
    """Per row: test, val (the checkpoint's validation part, held out of fitting) or train."""
    parts = np.where(splits == "test", "test", "train").astype(object)
    for start, stop in config.get("val_spans", []):
        parts[start:stop] = "val"
    return parts.astype(str)


@dataclass
class WorkdirPredictions:
    """Every method's class probabilities over a workdir's frames, with what was chosen and said."""

    keys: pl.DataFrame
    probabilities: dict[str, np.ndarray]  # method name (decoded ones too) -> [n, C]
    predicted: dict[str, np.ndarray]  # method name -> [n] class index
    modes: dict[str, str]  # method name -> segment | stream | frame
    choices: dict[str, WeightChoice]  # decoded network methods -> the network factor's weight
    inputs: list[Path]
    notes: list[str]
    meta: dict[str, Any]  # frames.parquet's metadata


def predict_workdir(workdir: Path, mln_mode: str, decodes: Sequence[str] = ("none",),
                    methods: Sequence[str] = METHODS) -> WorkdirPredictions:
    """Run every trained network and the MLN over a workdir's frames and fuse and decode them.

    A method whose inputs are absent is left out with a note. A decoded network method's network
    factor weight is chosen on the validation part its network held out in training (never on test);
    a network trained without one keeps the weight 1, and a note says so.
    """
    from stages.mln import classifier

    workdir = Path(workdir)
    frames_path = workdir / artifacts.FRAMES
    frames, meta = artifacts.read_table(frames_path, "frames")
    classes, source = list(meta["classes"]), meta.get("source", "")
    data = FrameData.from_frames(frames)
    notes: list[str] = []
    inputs = [frames_path]

    predicates = weights = scores = p_mln = None
    if (workdir / artifacts.WEIGHTS).exists():
        predicates, weights, mln_inputs = read_mln(workdir, frames)
        inputs += mln_inputs
        scores = classifier.class_scores(predicates, weights, len(classes))
        p_mln = np.exp(classifier.class_log_probs(scores, mln_mode, source))
    else:
        notes.append(f"no {artifacts.WEIGHTS}: mln, priorlayer, conflation and combined left out "
                     "(run `mlnseq learn-weights`)")

    checkpoints: dict[str, Checkpoint] = {}
    for network in dict.fromkeys(network_of(m) for m in methods if network_of(m)):
        if artifacts.checkpoint_path(workdir, network).exists():
            checkpoints[network] = load_checkpoint(workdir, network, meta)
            inputs.append(artifacts.checkpoint_path(workdir, network))
        else:
            notes.append(f"no {network} model: {network} left out (run `mlnseq train --method {network}`)")
    parts = {n: parts_of(c.config, data.splits) for n, c in checkpoints.items()}
    log_p_network: dict[str, np.ndarray] = {}
    for network, checkpoint in checkpoints.items():
        if network == "priorlayer" and scores is None:
            continue
        prior = None if network == "lstm" else prior_input(scores, checkpoint.config["prior"], source)
        spans = sequences.sequences(checkpoint.mode, data.episodes, parts[network], data.labels)
        set_threads()
        log_p_network[network] = predict_log_probs(
            checkpoint.model, spans, checkpoint.standardise(data.features), prior).astype(np.float64)

    available = [m for m in methods if (network_of(m) is None or network_of(m) in log_p_network)
                 and (m in NETWORKS or p_mln is not None)]
    if not available:
        raise MissingArtifact(f"nothing to predict with in {workdir}: run `mlnseq learn-weights` "
                              "and/or `mlnseq train` first")
    result = WorkdirPredictions(frames.select(artifacts.KEY_COLUMNS), {}, {}, {}, {}, inputs, notes, meta)
    for method in available:
        network = network_of(method)
        probabilities = fuse(method, None if network is None else np.exp(log_p_network[network]), p_mln)
        result.probabilities[method], result.predicted[method] = probabilities, probabilities.argmax(1)
        result.modes[method] = "frame" if network is None else checkpoints[network].mode

    decoding = [d for d in decodes if d != "none"]
    if not decoding:
        return result
    if weights is None:
        raise BadInput(f"--decode {','.join(decoding)} needs the MLN's factors: run `mlnseq learn-weights` first")
    from stages.mln.factors import MLNFactors

    columns = artifacts.feature_columns(predicates)
    mln = MLNFactors.from_weights(weights, columns, len(classes))
    if not mln.temporal:
        notes.append(f"{artifacts.WEIGHTS} has no temporal formula (Next): decoding uses uniform transitions")
    evidence = predicates.select(columns).to_numpy().astype(bool)
    unvalidated = sorted(n for n, c in checkpoints.items() if not c.config.get("val_spans"))
    if unvalidated:
        notes.append(f"{', '.join(unvalidated)} trained without a validation part (`train --select val_accuracy`): "
                     "its decoded methods keep the network factor's weight 1")
    split_parts = np.where(data.splits == "test", "test", "train")
    for kind in decoding:
        for method in available:
            network, name = network_of(method), decoded_name(method, kind)
            rows = parts.get(network, split_parts)
            starts = chain_starts(data.episodes, rows)
            weight = 1.0
            if network is not None:
                choice = choose_network_weight(method, kind, mln, evidence, starts, log_p_network[network],
                                               data.labels, rows == "val")
                result.choices[name], weight = choice, choice.weight
            factors = chain_of(method, mln, evidence, starts, log_p_network.get(network), weight)
            result.probabilities[name], result.predicted[name] = decode(kind, factors)
            result.modes[name] = result.modes[method]
    return result
