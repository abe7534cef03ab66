"""A trained model turned into class probabilities: checkpoints, standardisation, the MLN input, the
networks, fusion (eq. 16) and decoding.

`conflate` (every method over a workdir), `predict` (a model file over new recordings), `stream` (one
frame at a time) and the Python API all call this module; `train` fits and saves what it loads.
torch is imported only where a network runs, so the method names and options here stay light.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from stages import artifacts, sequences
from stages.errors import BadInput, StaleArtifact

if TYPE_CHECKING:
    import torch

    from stages.models import SequenceClassifier, StreamingClassifier

NETWORKS = ("lstm", "priorlayer")
METHODS = ("lstm", "mln", "priorlayer", "conflation", "combined")
FUSED = {"conflation": "lstm", "combined": "priorlayer"}  # a fused method -> the network it conflates
PRIORS = ("paper", "logprob")  # the c2c input of PriorLayer: clamped MLN sums (the authors') or log-probs
MLN_MODES = ("paper", "exact")
CHECKPOINT_FORMAT = 1
INFERENCE_BATCH = 256
EPSILON = 1e-7  # keeps eq. 16 defined when one side is exactly 0 and the other exactly 1


def network_of(method: str) -> str | None:
    """The network a method runs (None for the MLN alone)."""
    return FUSED.get(method, method if method in NETWORKS else None)


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


def mln_class_scores(workdir: Path, frames: pl.DataFrame, n_classes: int) -> tuple[np.ndarray, list[Path]]:
    """Per-frame summed MLN formula weights per class, from predicates.parquet and weights.parquet."""
    from stages.mln import classifier

    predicates_path, weights_path = workdir / artifacts.PREDICATES, workdir / artifacts.WEIGHTS
    predicates, _ = artifacts.read_table(predicates_path)
    weights, _ = artifacts.read_table(weights_path)
    keys = ["episode", "frame"]
    if predicates.height != frames.height or not predicates.select(keys).equals(frames.select(keys)):
        raise StaleArtifact(f"{predicates_path} does not hold the frames of {artifacts.FRAMES}; "
                            "rerun `mlnseq binarize`")
    return classifier.class_scores(predicates, weights, n_classes), [predicates_path, weights_path]


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
