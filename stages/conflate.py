"""conflate: run every trained model and the MLN classifier on all frames and combine them (eq. 16).

Conflation of two class distributions, per class k (eq. 16):
    P_C(k) = P_L(k)·P_K(k) / (P_L(k)·P_K(k) + (1 − P_L(k))·(1 − P_K(k)))
and the prediction is argmax_k P_C(k). The stored conflated values are eq. 16 as it stands, not
renormalised to sum to 1 (the argmax is the same either way).

Methods: lstm, priorlayer (the networks), mln (the MLN classifier alone), conflation (lstm + MLN)
and combined (priorlayer + MLN). A method whose inputs are absent is left out with a note.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from stages import artifacts, sequences, train
from stages.errors import BadInput, MissingArtifact

MLN_MODES = ("paper", "exact")
METHODS = ("lstm", "mln", "priorlayer", "conflation", "combined")
EPSILON = 1e-7  # keeps eq. 16 defined when one side is exactly 0 and the other exactly 1


@dataclass(frozen=True)
class ConflateOptions:
    """Options of `mlnseq conflate`."""

    mln_mode: str = "paper"

    def validate(self) -> None:
        if self.mln_mode not in MLN_MODES:
            raise BadInput(f"unknown --mln-mode {self.mln_mode!r}: choose one of {', '.join(MLN_MODES)}")


def conflation(p_network: np.ndarray, p_mln: np.ndarray) -> np.ndarray:
    """Eq. 16 per class on [n, C] probabilities."""
    a = np.clip(np.asarray(p_network, dtype=np.float64), EPSILON, 1 - EPSILON)
    b = np.clip(np.asarray(p_mln, dtype=np.float64), EPSILON, 1 - EPSILON)
    return a * b / (a * b + (1 - a) * (1 - b))


def prob_columns(method: str, n_classes: int) -> list[str]:
    return [f"{method}_p{k}" for k in range(n_classes)]


def pred_column(method: str) -> str:
    return f"{method}_pred"


def predictions_table(keys: pl.DataFrame, probabilities: dict[str, np.ndarray]) -> pl.DataFrame:
    """Keys, then per method its argmax (int16) and its class probabilities (float32)."""
    columns = [keys]
    for method, probs in probabilities.items():
        columns.append(pl.DataFrame(
            [pl.Series(pred_column(method), probs.argmax(1), dtype=pl.Int16)]
            + [pl.Series(name, probs[:, k], dtype=pl.Float32)
               for k, name in enumerate(prob_columns(method, probs.shape[1]))]
        ))
    return pl.concat(columns, how="horizontal")


def network_probabilities(checkpoint: train.Checkpoint, data: train.FrameData) -> np.ndarray:
    """Run a trained network over every frame in its sequence mode; class probabilities [n, C]."""
    import torch

    train.set_threads()
    spans = sequences.sequences(checkpoint.mode, data.episodes, data.splits, data.labels)
    features = checkpoint.standardise(data.features)
    log_probs = train.predict_log_probs(checkpoint.model, spans, features, data.prior, torch.device("cpu"))
    return np.exp(log_probs.astype(np.float64))


@dataclass(frozen=True)
class ConflateResult:
    path: Path
    methods: list[str]
    notes: list[str]


def run(workdir: Path, options: ConflateOptions) -> ConflateResult:
    """Read frames, models and MLN weights from ``workdir``; write ``predictions.parquet``."""
    options.validate()
    workdir = Path(workdir)
    frames_path = workdir / artifacts.FRAMES
    frames, meta = artifacts.read_table(frames_path, "frames")
    n_classes, source = len(meta["classes"]), meta.get("source", "")
    notes: list[str] = []
    inputs = [frames_path]

    scores = None
    if (workdir / artifacts.WEIGHTS).exists():
        scores, mln_inputs = train.mln_class_scores(workdir, frames, n_classes)
        inputs += mln_inputs
    else:
        notes.append(f"no {artifacts.WEIGHTS}: mln, priorlayer, conflation and combined left out "
                     "(run `mlnseq learn-weights`)")

    from stages.mln import classifier

    probabilities: dict[str, np.ndarray] = {}
    p_mln = None if scores is None else np.exp(classifier.class_log_probs(scores, options.mln_mode, source))
    checkpoints = {}
    for method in train.METHODS:
        if artifacts.checkpoint_path(workdir, method).exists():
            checkpoints[method] = train.load_checkpoint(workdir, method, meta)
            inputs.append(artifacts.checkpoint_path(workdir, method))
        else:
            notes.append(f"no {method} model: {method} left out (run `mlnseq train --method {method}`)")

    if "lstm" in checkpoints:
        probabilities["lstm"] = network_probabilities(checkpoints["lstm"], train.FrameData.from_frames(frames))
    if p_mln is not None:
        probabilities["mln"] = p_mln
    if "priorlayer" in checkpoints and scores is not None:
        kind = checkpoints["priorlayer"].config["prior"]
        prior = train.prior_input(scores, kind, source)
        probabilities["priorlayer"] = network_probabilities(
            checkpoints["priorlayer"], train.FrameData.from_frames(frames, prior))
    if p_mln is not None:
        for network, combined in (("lstm", "conflation"), ("priorlayer", "combined")):
            if network in probabilities:
                probabilities[combined] = conflation(probabilities[network], p_mln)
    if not probabilities:
        raise MissingArtifact(f"nothing to predict with in {workdir}: run `mlnseq learn-weights` "
                              "and/or `mlnseq train` first")

    methods = [m for m in METHODS if m in probabilities]
    table = predictions_table(frames.select(artifacts.KEY_COLUMNS), {m: probabilities[m] for m in methods})
    modes = {m: "frame" for m in methods}
    for network, combined in (("lstm", "conflation"), ("priorlayer", "combined")):
        if network in checkpoints:
            modes[network] = modes[combined] = checkpoints[network].mode
    path = artifacts.write_table(
        table, workdir / artifacts.PREDICTIONS, "predictions",
        {"methods": methods, "modes": {m: modes[m] for m in methods}, "mln_mode": options.mln_mode,
         "classes": meta["classes"], "source": source},
        inputs=inputs,
    )
    return ConflateResult(path, methods, notes)
