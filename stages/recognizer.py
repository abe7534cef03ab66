"""A trained model turned into class probabilities: checkpoints, standardisation, the MLN input, the
networks, fusion (eq. 16) and decoding.

`conflate` (every method over a workdir), `predict` (a model file over new recordings), `stream` (one
frame at a time) and the Python API all call this module; `train` fits and saves what it loads. The
networks run in numpy (stages/networks/network.py); torch is imported only to read and write the workdir's
checkpoints, so a model file is recognised without it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from stages import artifacts, model_file, sequences
from stages.errors import BadInput, MissingArtifact, StaleArtifact
from stages.model_file import NETWORK, SPEC, WEIGHTS
from stages.networks.network import Network, StreamingNetwork
from stages.mln import chain

if TYPE_CHECKING:
    from stages.predicate_spec import PredicateSpec
    from stages.mln.factors import MLNFactors
    from stages.networks.classifier import SequenceClassifier

NETWORKS = ("lstm", "priorlayer")
METHODS = ("lstm", "mln", "priorlayer", "conflation", "combined")
FUSED = {"conflation": "lstm", "combined": "priorlayer"}  # a fused method -> the network it conflates
PRIORS = ("paper", "logprob")  # the c2c input of PriorLayer: clamped MLN sums (the authors') or log-probs
MLN_MODES = ("paper", "exact")
DECODES = ("none", "filter", "viterbi")  # none: per frame; filter: online chain; viterbi: offline chain
NETWORK_WEIGHTS = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)  # the network factor's weights tried on validation
CHECKPOINT_FORMAT = 1
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
    method, plus, decode = name.partition("+")
    if method not in METHODS or (plus and decode not in DECODES[1:]):
        raise BadInput(f"unknown {option} {name!r}: choose one of {', '.join(METHODS)}, "
                       f"optionally with +filter or +viterbi (e.g. combined+filter)")
    return method, decode or "none"


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


@dataclass(frozen=True)
class Checkpoint:
    """A trained network (in numpy) with the configuration its checkpoint embeds."""

    network: Network
    config: dict[str, Any]

    @property
    def mode(self) -> str:
        return self.config["mode"]


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
    return Checkpoint(Network.from_state(config["model"], saved["state_dict"], config["mean"], config["std"]), config)


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


def mln_class_scores(workdir: Path, frames: pl.DataFrame, classes: int | Sequence[str]) -> tuple[np.ndarray, list[Path]]:
    """Per-frame summed MLN formula weights per class, from predicates.parquet and weights.parquet."""
    from stages.mln import classifier

    predicates, weights, inputs = read_mln(workdir, frames)
    return classifier.class_scores(predicates, weights, classes), inputs


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


def frame_factor(method: str, mln_unary: np.ndarray, log_p_network: np.ndarray | None, weight: float) -> np.ndarray:
    """A decoded method's per-frame log-potentials: the MLN's per-frame factor (mln, conflation, combined)
    plus ``weight`` times the network's log-probabilities (every method but mln)."""
    factor = mln_unary if method == "mln" or method in FUSED else np.zeros_like(mln_unary)
    return factor if method == "mln" else factor + weight * np.asarray(log_p_network, dtype=np.float64)


def chain_of(method: str, mln: MLNFactors, evidence: np.ndarray, starts: np.ndarray,
             log_p_network: np.ndarray | None, weight: float) -> chain.ChainFactors:
    """The chain a decoded method runs: its frame factors and the MLN's transition factors."""
    factors = mln.chain(evidence, starts)
    return replace(factors, unary=frame_factor(method, factors.unary, log_p_network, weight))


def decode_chain(kind: str, factors: chain.ChainFactors) -> chain.Decoded:
    """Class probabilities [T, C], predicted classes [T] and the frames where a dead end restarted the chain:
    filter is online (each frame from the frames up to it); viterbi is offline (the most probable path, with
    forward-backward marginals as probabilities)."""
    return chain.decode(factors, kind)


def restart_note(name: str, restarts: Sequence[tuple[Any, int]], shown: int = 5) -> str:
    """One line naming where a decoded method's chain restarted: (episode, frame) of each dead end."""
    where = ", ".join(f"episode {episode} frame {frame}" for episode, frame in restarts[:shown])
    more = f" and {len(restarts) - shown} more" if len(restarts) > shown else ""
    return (f"{name}: the chain restarted at {len(restarts)} frame(s) that no allowed transition reaches (a missed "
            f"episode boundary, or evidence that breaks a hard rule): {where}{more}")


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
        tried[weight] = float((decode_chain(kind, factors).path == labels[validation]).mean())
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
    validation: dict[str, float]  # method name -> frame accuracy on the networks' validation part (if any)
    inputs: list[Path]
    notes: list[str]
    meta: dict[str, Any]  # frames.parquet's metadata
    restarts: dict[str, list[tuple[Any, int]]] = field(default_factory=dict)  # decoded method -> (episode, frame)


def predict_workdir(workdir: Path, mln_mode: str, decodes: Sequence[str] = ("none",),
                    methods: Sequence[str] = METHODS, network_weight: float | None = None) -> WorkdirPredictions:
    """Run every trained network and the MLN over a workdir's frames and fuse and decode them.

    A method whose inputs are absent is left out with a note. A decoded network method's network
    factor weight is ``network_weight`` when given, else chosen on the validation part its network
    held out in training (never on test); a network trained without one keeps the weight 1, and a
    note says so.
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
        scores = classifier.class_scores(predicates, weights, classes)
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
        log_p_network[network] = checkpoint.network.log_probs(spans, data.features, prior)

    available = [m for m in methods if (network_of(m) is None or network_of(m) in log_p_network)
                 and (m in NETWORKS or p_mln is not None)]
    if not available:
        raise MissingArtifact(f"nothing to predict with in {workdir}: run `mlnseq learn-weights` "
                              "and/or `mlnseq train` first")
    result = WorkdirPredictions(frames.select(artifacts.KEY_COLUMNS), {}, {}, {}, {}, {}, inputs, notes, meta)
    for method in available:
        network = network_of(method)
        probabilities = fuse(method, None if network is None else np.exp(log_p_network[network]), p_mln)
        result.probabilities[method], result.predicted[method] = probabilities, probabilities.argmax(1)
        result.modes[method] = "frame" if network is None else checkpoints[network].mode

    validation = np.zeros(len(frames), dtype=bool)  # every network holds out the same units, given the same options
    for network_parts in parts.values():
        validation |= network_parts == "val"
    decoding = [d for d in decodes if d != "none"]
    if not decoding:
        return _scored(result, data.labels, validation)
    if weights is None:
        raise BadInput(f"--decode {','.join(decoding)} needs the MLN's factors: run `mlnseq learn-weights` first")
    from stages.mln.factors import MLNFactors

    columns = artifacts.feature_columns(predicates)
    mln = MLNFactors.from_weights(weights, columns, classes)
    if not mln.temporal:
        notes.append(f"{artifacts.WEIGHTS} has no temporal formula (Next): decoding uses uniform transitions")
    evidence = predicates.select(columns).to_numpy().astype(bool)
    unvalidated = sorted(n for n, c in checkpoints.items() if not c.config.get("val_spans"))
    if unvalidated and network_weight is None:
        notes.append(f"{', '.join(unvalidated)} trained without a validation part (`train --select last` or `val_accuracy`): "
                     "its decoded methods keep the network factor's weight 1")
    split_parts = np.where(data.splits == "test", "test", "train")
    for kind in decoding:
        for method in available:
            network, name = network_of(method), decoded_name(method, kind)
            rows = parts.get(network, split_parts)
            starts = chain.chain_starts(data.episodes, rows)
            weight = 1.0
            if network is not None and network_weight is not None:
                weight = network_weight
            elif network is not None:
                choice = choose_network_weight(method, kind, mln, evidence, starts, log_p_network[network],
                                               data.labels, rows == "val")
                result.choices[name], weight = choice, choice.weight
            factors = chain_of(method, mln, evidence, starts, log_p_network.get(network), weight)
            decoded = decode_chain(kind, factors)
            result.probabilities[name], result.predicted[name] = decoded.probabilities, decoded.path
            if len(decoded.restarts):
                keys, names = result.keys[decoded.restarts], meta.get("episode_names") or []  # the user's ids, if any
                result.restarts[name] = [(names[e] if 0 <= e < len(names) else e, f)
                                         for e, f in zip(keys["episode"].to_list(), keys["frame"].to_list())]
                notes.append(restart_note(name, result.restarts[name]))
            result.modes[name] = result.modes[method]
    return _scored(result, data.labels, validation)


def _scored(result: WorkdirPredictions, labels: np.ndarray, validation: np.ndarray) -> WorkdirPredictions:
    """Each method's frame accuracy on the validation rows: what a choice among methods may look at."""
    if validation.any():
        result.validation.update({name: float((predicted[validation] == labels[validation]).mean())
                                  for name, predicted in result.predicted.items()})
    return result


# --- the Recognizer (export, info, predict, stream, the Python API) ---------------------------------


def needs_mln(method: str, decode: str) -> bool:
    """Whether a method with this decoding uses the MLN (and so the predicate spec and the weights)."""
    return method != "lstm" or decode != "none"


@dataclass(frozen=True)
class Prediction:
    """One frame's recognition: the class, its name and every class's probability (in class order)."""

    frame: int  # index within the episode
    label: int
    name: str
    probabilities: np.ndarray
    restarted: bool = False  # the frame was a dead end (no class possible given the previous): the chain started anew


class Recognizer:
    """A trained recogniser loaded from a model file: frames in, class probabilities out.

    ``step`` takes one frame at a time (a mapping of feature name to value, or the values in feature
    order) and keeps the state a live stream needs: the previous frame for the change predicates, the
    network's hidden state and the filter's belief. ``reset`` starts a new episode. ``predict`` runs
    whole recordings at once, offline decoding (viterbi) included.
    """

    def __init__(self, entries: dict[str, bytes], where: str = "<model>"):
        from stages.predicate_rules import StreamingBinarizer
        from stages.mln.factors import MLNFactors, parse_weights

        model = model_file.parse_model(entries, where)
        self.manifest = manifest = model.manifest
        self.method, self.decode = manifest["method"], manifest["decode"]
        network = manifest["network"]
        if (self.method not in METHODS or self.decode not in DECODES or manifest["mln_mode"] not in MLN_MODES
                or (network or {}).get("name") != network_of(self.method)
                or (network or {}).get("prior") not in (None, *PRIORS)):
            raise BadInput(f"{where}: its manifest's method {self.method!r}, decoding {self.decode!r}, mln-mode "
                           f"{manifest['mln_mode']!r} or network {(network or {}).get('name')!r} is not one this "
                           f"mlnseq runs: export it again with `mlnseq export`")
        needed = [NETWORK] * (network_of(self.method) is not None) + [SPEC, WEIGHTS] * needs_mln(self.method, self.decode)
        missing = [name for name in needed if name not in entries]
        if missing:
            raise BadInput(f"{where} lacks {', '.join(missing)}, which a {decoded_name(self.method, self.decode)} "
                           "model needs: export it again with `mlnseq export`")
        self.classes: list[str] = list(manifest["classes"])
        self.features: list[str] = list(manifest["features"])
        self.network_weight = float(manifest.get("network_weight") or 1.0)
        self._feature_index = {name: i for i, name in enumerate(self.features)}
        self.network = model.network
        self.prior = (manifest.get("network") or {}).get("prior")  # PriorLayer's MLN input, if it has one
        self.spec: PredicateSpec | None = None
        self.weights: pl.DataFrame | None = None
        self.mln: MLNFactors | None = None
        if needs_mln(self.method, self.decode):
            self.spec, self.weights = model.spec, model.weights
            self.columns = [c for columns in self.spec.columns().values() for c in columns]
            self.binarizer = StreamingBinarizer(self.spec, self.features)
            formulas = parse_weights(self.weights, self.columns, self.classes)
            self._per_frame = [f for f in formulas if not f.temporal]
            if self.decode != "none":
                self.mln = MLNFactors(formulas, self.columns, len(self.classes))
        self._mln_row = lru_cache(maxsize=4096)(self._mln_of)
        self.restarts: list[tuple[Any, int]] = []  # where the last ``predict`` restarted its chain: (episode, frame)
        self.reset()

    @classmethod
    def load(cls, path: str | Path) -> Recognizer:
        """Load an ``.mlnseq`` file written by `mlnseq export`."""
        return cls(model_file.read_model(Path(path)), str(path))

    # -- one frame at a time ---------------------------------------------------------------------

    def reset(self) -> None:
        """The next frame starts a new episode."""
        self._frame = 0
        self._evidence: np.ndarray | None = None
        self._network = StreamingNetwork(self.network) if self.network is not None else None
        self._filter = chain.Filter(len(self.classes)) if self.decode != "none" else None
        if self.spec is not None:
            self.binarizer.reset()

    def vector(self, frame: Mapping[str, Any] | Sequence[float] | np.ndarray) -> np.ndarray:
        """A frame's feature values in the model's order, as float64; refuses missing and non-finite values."""
        if isinstance(frame, Mapping):
            missing = [name for name in self.features if name not in frame]
            if missing:
                raise BadInput(f"missing feature {', '.join(map(repr, missing))}")
            values = [frame[name] for name in self.features]
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
                bad = next(n for n, v in zip(self.features, values)
                           if not isinstance(v, (int, float)) or isinstance(v, bool))
                raise BadInput(f"feature {bad!r} is {frame[bad]!r}, not a number")
            vector = np.array(values, dtype=np.float64)
        else:
            vector = np.asarray(frame, dtype=np.float64).reshape(-1)
            if vector.shape != (len(self.features),):
                raise BadInput(f"a frame has {len(self.features)} feature values ({', '.join(self.features)}), "
                               f"got {vector.size}")
        if not np.isfinite(vector).all():
            bad = self.features[int(np.flatnonzero(~np.isfinite(vector))[0])]
            raise BadInput(f"feature {bad!r} is {vector[self._feature_index[bad]]}, not a finite number")
        return vector

    def step(self, frame: Mapping[str, Any] | Sequence[float] | np.ndarray) -> Prediction:
        """Recognise the next frame of the current episode from its raw features."""
        x = self.vector(frame)
        # predicates from the values as a frames table holds them (float32), as `predict` binarizes them
        evidence = self.binarizer.step(x.astype(np.float32)) if self.spec is not None else None
        p_mln = prior = unary = None
        if evidence is not None:
            p_mln, prior, unary = self._mln_row(evidence.tobytes())
        log_p_network = None if self._network is None else self._network.step(x, prior)
        if self._filter is None:
            probabilities = fuse(self.method, None if log_p_network is None else np.exp(log_p_network), p_mln)
        else:
            factor = frame_factor(self.method, unary, log_p_network, self.network_weight)
            pairwise = None if self._evidence is None else self.mln.pairwise(self._evidence[None], evidence[None])[0]
            probabilities = np.exp(self._filter.step(factor, pairwise))
        self._evidence = evidence
        label = int(np.argmax(probabilities))
        restarted = self._filter is not None and self._filter.restarted
        prediction = Prediction(self._frame, label, self.classes[label], probabilities, restarted)
        self._frame += 1
        return prediction

    def _mln_of(self, evidence: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The MLN's per-frame class probabilities, PriorLayer input and chain factor of one evidence row."""
        from stages.mln import classifier
        from stages.mln.factors import frame_scores

        row = np.frombuffer(evidence, dtype=bool)[None]
        scores = frame_scores(self._per_frame, row, self.columns, len(self.classes), classifier.HARD_WEIGHT)
        p_mln, prior = self._mln_outputs(scores)
        unary = self.mln.unary(row)[0] if self.mln is not None else None
        return p_mln[0], None if prior is None else prior[0], unary

    def _mln_outputs(self, scores: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The MLN's class probabilities [n, C] from its class scores, and PriorLayer's input if the network has one."""
        from stages.mln import classifier

        source = self.manifest.get("source", "")
        p_mln = np.exp(classifier.class_log_probs(scores, self.manifest["mln_mode"], source))
        return p_mln, None if self.prior is None else prior_input(scores, self.prior, source)

    # -- whole recordings --------------------------------------------------------------------------

    def predict(self, features: np.ndarray, episodes: np.ndarray | None = None,
                decode: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(class probabilities [T, C], predicted classes [T]) of recordings given as raw features [T, F] in the
        model's feature order, rows grouped by ``episodes`` (default: one episode). ``decode`` overrides the
        model's decoding (e.g. viterbi for a filter model: the same factors, decoded offline). Where a frame is a
        dead end (no class possible given the previous ones), the chain restarts there, as ``step`` does:
        ``restarts`` then lists (episode, frame within it) of each."""
        decode = self.decode if decode is None else decode
        if decode != self.decode and decode != "none" and self.mln is None:
            raise BadInput(f"--decode {decode}: this model was exported without decoding, so it holds no "
                           "transition factors; export it again with --decode filter or viterbi")
        features = np.asarray(features, dtype=np.float64)
        episodes = np.zeros(len(features), dtype=np.int64) if episodes is None else np.asarray(episodes)
        self.restarts = []
        spans = sequences.runs(episodes)
        frame_of = np.concatenate([np.arange(s.stop - s.start) for s in spans]) if spans else np.zeros(0, np.int64)
        starts = chain.chain_starts(episodes)
        p_mln = prior = evidence = None
        if self.spec is not None:
            from stages import predicate_rules
            from stages.mln import classifier

            # binarized as frames.parquet holds them: float32
            evidence = predicate_rules.features_evidence(self.spec, self.features, features.astype(np.float32), starts)
            predicates = pl.DataFrame({column: evidence[:, i] for i, column in enumerate(self.columns)})
            p_mln, prior = self._mln_outputs(classifier.class_scores(predicates, self.weights, self.classes))
        log_p_network = None if self.network is None else self.network.log_probs(spans, features, prior)
        if decode == "none":
            probabilities = fuse(self.method, None if log_p_network is None else np.exp(log_p_network), p_mln)
            return probabilities, probabilities.argmax(1)
        factors = chain_of(self.method, self.mln, evidence, starts, log_p_network, self.network_weight)
        decoded = decode_chain(decode, factors)
        self.restarts = [(episodes[t].item(), int(frame_of[t])) for t in decoded.restarts]
        return decoded.probabilities, decoded.path
