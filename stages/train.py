"""train: fit a network (LSTM, GRU or causal TCN: stages/networks/), alone or with the MLN PriorLayer, on the training split.

The core (:func:`fit`) works on arrays; :func:`run` reads ``frames.parquet`` (and, for PriorLayer,
``predicates.parquet`` + ``weights.parquet``), writes ``models/<method>.pt`` and its per-epoch log.

Validation part: with ``select="last"`` or ``"val_accuracy"`` the last ``val_fraction`` of the training
units (segments in segment mode, windows in stream mode, in file order) is held out of training and scored
each epoch; the checkpoint records it, and conflate chooses its weights on it. ``last`` keeps the last
epoch, ``val_accuracy`` the epoch with the best frame accuracy on that part. With ``none`` every training
unit is used and the last epoch is kept. The test split is only ever logged (for the curves), never used.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq import networks
from mlnseq.timeline import sequences
from mlnseq.recognition import folds as folding
from mlnseq.catalog.errors import BadInput, check_choice
from mlnseq.model.checkpoints import save_checkpoint
from mlnseq.catalog.methods import NETWORKS, PRIORS
from mlnseq.recognition.recognizer import prior_input
from mlnseq.recognition.workdir_inputs import FrameData, mln_class_scores

if TYPE_CHECKING:  # torch loads only when a network is built or run
    import torch

    from mlnseq.networks.classifier import SequenceClassifier

METHODS = NETWORKS
SELECTS = ("none", "last", "val_accuracy")
DEVICES = ("auto", "cpu", "cuda")


@dataclass(frozen=True)
class TrainOptions:
    """Options of `mlnseq train`."""

    method: str = "lstm"
    seed: int = 0
    epochs: int = 100
    mode: str = "segment"
    cell: str = "lstm"  # the network type: a name in mlnseq.networks.TYPES
    prior: str = "paper"  # c2c input of PriorLayer: paper (clamped MLN sums) | logprob (MLN log-probs)
    select: str = "none"
    device: str = "auto"
    train_fraction: float = 1.0
    batch_size: int = 4
    window: int = 64  # stream mode: training window length in frames
    hidden_size: int = 32
    learning_rate: float = 0.1
    val_fraction: float = 0.2
    smoothing: float = 0.0  # tcn: weight of MS-TCN's smoothing loss
    folds: int | None = None  # cross-validation folds (stages/recognition/folds.py); None: stream mode's default, 0: none

    def validate(self) -> None:
        choices = {"method": METHODS, "mode": sequences.MODES, "cell": networks.CELLS, "prior": PRIORS,
                   "select": SELECTS, "device": DEVICES}
        for name, allowed in choices.items():
            check_choice(name, getattr(self, name), allowed)
        if not 0 < self.train_fraction <= 1:
            raise BadInput(f"--train-fraction must be in (0, 1], got {self.train_fraction}")
        if not 0 < self.val_fraction < 1:
            raise BadInput(f"--val-fraction must be in (0, 1), got {self.val_fraction}")
        for name in ("epochs", "batch_size", "window", "hidden_size"):
            if getattr(self, name) < 1:
                raise BadInput(f"--{name.replace('_', '-')} must be at least 1, got {getattr(self, name)}")
        if self.smoothing < 0:
            raise BadInput(f"--smoothing must be at least 0, got {self.smoothing}")
        if self.folds is not None and self.folds < 0:
            raise BadInput(f"--folds {self.folds}: use 0 (no folds) or at least 2 folds")
        if not self.learning_rate > 0:
            raise BadInput(f"--learning-rate must be positive, got {self.learning_rate}")
        if self.device == "cuda":
            import torch

            if not torch.cuda.is_available():
                raise BadInput("--device cuda: no CUDA GPU is visible to torch here; use --device cpu")


@dataclass
class Trained:
    """What :func:`fit` returns: the kept network, its standardisation and the per-epoch log."""

    model: SequenceClassifier
    mean: np.ndarray
    std: np.ndarray
    log: pl.DataFrame
    kept_epoch: int
    n_train_units: int
    n_val_units: int
    val_spans: list[tuple[int, int]]  # rows of the validation part: held out of fitting, scored each epoch
    warnings: list[str] = field(default_factory=list)


def resolve_device(name: str) -> torch.device:
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def set_threads() -> None:
    """Small recurrent nets run fastest on one thread (measured: 8x faster than two on this 2-core CPU)."""
    import torch

    torch.set_num_threads(1)


def assign_parts(data: FrameData, options: TrainOptions) -> tuple[np.ndarray, list[slice], list[slice]]:
    """Mark every row fit / val / test / unused; return the parts and the fit and val training units."""
    parts = np.where(data.splits == "train", "train", "test").astype(object)
    units = sequences.training_units(options.mode, data.episodes, parts, data.labels, options.window)
    units = [u for u in units if parts[u.start] == "train"]
    if not units:
        raise BadInput("frames.parquet has no training frames: rerun `mlnseq collect` with a training split")
    val_units: list[slice] = []
    if options.select != "none":
        if len(units) < 2:
            raise BadInput(f"--select {options.select} needs at least 2 training sequences; use --select none")
        n_val = max(1, round(options.val_fraction * len(units)))
        units, val_units = units[:-n_val], units[-n_val:]
    fit_units = units[: max(1, math.ceil(options.train_fraction * len(units)))]
    for unit in units[len(fit_units):]:
        parts[unit] = "unused"
    for unit in val_units:
        parts[unit] = "val"
    for unit in fit_units:
        parts[unit] = "fit"
    return parts.astype(str), fit_units, val_units


def predict_log_probs(
    model: SequenceClassifier, spans: list[slice], features: np.ndarray, prior: np.ndarray | None,
    device: torch.device,
) -> np.ndarray:
    """Class log-probabilities of every row covered by ``spans`` (each span a fresh sequence): the per-epoch
    evaluation of training (recognition runs the trained network through stages/networks/network.py)."""
    import torch

    model.eval()
    out = np.zeros((len(features), model.config.n_classes), dtype=np.float32)
    ordered = sorted(spans, key=lambda s: s.stop - s.start)  # similar lengths share a batch
    for i in range(0, len(ordered), networks.INFERENCE_BATCH):
        batch = ordered[i : i + networks.INFERENCE_BATCH]
        x = torch.from_numpy(sequences.pad(batch, features)).to(device)
        p = None if prior is None else torch.from_numpy(sequences.pad(batch, prior)).to(device)
        with torch.inference_mode():
            log_probs = model(x, p)[0].cpu().numpy()
        for j, span in enumerate(batch):
            out[span] = log_probs[j, : span.stop - span.start]
    return out


def _accuracy_and_loss(log_probs: np.ndarray, labels: np.ndarray, rows: np.ndarray) -> tuple[float, float]:
    if not rows.any():
        return float("nan"), float("nan")
    lp = log_probs[rows]
    y = labels[rows]
    return float((lp.argmax(1) == y).mean()), float(-lp[np.arange(len(y)), y].mean())


def sgd_step(parameters: list[torch.Tensor], learning_rate: float) -> None:
    """Plain SGD, the update torch.optim.SGD makes without momentum (whose first use imports torch._dynamo,
    a second or two of every training run's start-up)."""
    import torch

    with torch.no_grad():
        for parameter in parameters:
            parameter.add_(parameter.grad, alpha=-learning_rate)


@dataclass(frozen=True)
class EpochDone:
    """What :func:`fit` tells its progress callback after each epoch (frame accuracy and NLL of the parts)."""

    epoch: int
    epochs: int
    loss: float  # on the training sequences
    train_accuracy: float
    val_accuracy: float | None  # None without a validation part (--select none)


Progress = Callable[[EpochDone], None]


def fit(
    data: FrameData, config: Any, options: TrainOptions, device: torch.device, progress: Progress | None = None,
    every_epoch: bool = True,
) -> Trained:
    """Train a network on the training split of ``data``; log train/val/test accuracy each epoch (or, not
    ``every_epoch``, after the last only: a fold network's log is not kept)."""
    import torch

    from mlnseq.networks.classifier import SequenceClassifier

    torch.manual_seed(options.seed)
    rng = np.random.default_rng(options.seed)
    parts, fit_units, val_units = assign_parts(data, options)
    fit_rows = parts == "fit"
    mean = data.features[fit_rows].mean(0)
    std = data.features[fit_rows].std(0)
    std = np.where(std > 1e-8, std, 1.0).astype(np.float32)
    features = ((data.features - mean) / std).astype(np.float32)
    prior = None if data.prior is None else data.prior.astype(np.float32)

    warnings = []
    missing = sorted(int(k) for k in set(data.labels[data.splits == "test"]) - set(data.labels[fit_rows]))
    if missing:
        warnings.append(f"classes {missing} occur in the test split but not in the training frames used; "
                        "the model cannot predict them well")

    model = SequenceClassifier(config).to(device)
    parameters = list(model.parameters())
    x_all = torch.from_numpy(sequences.pad(fit_units, features)).to(device)
    p_all = None if prior is None else torch.from_numpy(sequences.pad(fit_units, prior)).to(device)
    y_all = torch.from_numpy(sequences.pad(fit_units, data.labels, fill=-100)).to(device)
    n_all = torch.as_tensor(sequences.lengths(fit_units), device=device)
    eval_spans = {
        name: [s for s in sequences.sequences(options.mode, data.episodes, parts, data.labels)
               if parts[s.start] == part]
        for name, part in (("train", "fit"), ("val", "val"), ("test", "test"))
    }
    part_rows = {"train": fit_rows, "val": parts == "val", "test": parts == "test"}

    log_rows: list[dict[str, Any]] = []
    best_state, best_accuracy, kept_epoch = None, -1.0, options.epochs
    for epoch in range(1, options.epochs + 1):
        model.train()
        order = rng.permutation(len(fit_units))
        for start in range(0, len(order), options.batch_size):
            index = torch.as_tensor(order[start : start + options.batch_size], device=device)
            longest = int(n_all[index].max())
            x = x_all[index, :longest]
            p = None if p_all is None else p_all[index, :longest]
            y = y_all[index, :longest]
            log_probs = model(x, p)[0]
            frame_loss = torch.nn.functional.nll_loss(
                log_probs.reshape(-1, config.n_classes), y.reshape(-1), reduction="none", ignore_index=-100
            ).view(y.shape)
            # NLLLoss averaged within each sequence, then over sequences, as batch-size-1 SGD weighs them
            loss = (frame_loss.sum(1) / n_all[index]).mean()
            extra = model.auxiliary_loss(log_probs, y != -100)
            if extra is not None:
                loss = loss + extra
            for parameter in parameters:
                parameter.grad = None
            loss.backward()
            sgd_step(parameters, options.learning_rate)

        if not (every_epoch or epoch == options.epochs):
            continue
        spans = [s for name in eval_spans for s in eval_spans[name]]
        log_probs = predict_log_probs(model, spans, features, prior, device)
        measured = {}
        for name, rows in part_rows.items():
            if rows.any():
                accuracy, nll = measured[name] = _accuracy_and_loss(log_probs, data.labels, rows)
                log_rows.append({"epoch": epoch, "split": name, "accuracy": accuracy, "loss": nll})
        if progress is not None:
            val = measured.get("val")
            progress(EpochDone(epoch, options.epochs, measured["train"][1], measured["train"][0],
                               None if val is None else val[0]))
        if options.select == "val_accuracy":
            accuracy = measured["val"][0]
            if accuracy > best_accuracy:
                best_accuracy, kept_epoch = accuracy, epoch
                best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
    if best_state is not None:
        model.load_state_dict(best_state)
    log = pl.DataFrame(
        log_rows, schema={"epoch": pl.Int32, "split": pl.String, "accuracy": pl.Float64, "loss": pl.Float64}
    )
    return Trained(model.cpu(), mean.astype(np.float32), std, log, kept_epoch, len(fit_units), len(val_units),
                   [(u.start, u.stop) for u in val_units], warnings)


# --- the stage ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrainResult:
    checkpoint: Path
    log: Path
    trained: Trained
    device: str


def run(workdir: Path, options: TrainOptions, progress: Progress | None = None) -> TrainResult:
    """Train on ``workdir/frames.parquet``; write ``models/<method>.pt`` and ``models/<method>.log.parquet``."""
    options.validate()
    workdir = Path(workdir)
    set_threads()
    frames_path = workdir / artifacts.FRAMES
    frames, meta = artifacts.read_table(frames_path, "frames")
    n_classes = len(meta["classes"])
    inputs = [frames_path]
    prior = None
    if options.method == "priorlayer":
        scores, mln_inputs = mln_class_scores(workdir, frames, meta["classes"])
        prior = prior_input(scores, options.prior, meta.get("source", ""))
        inputs += mln_inputs
    data = FrameData.from_frames(frames, prior)
    config = networks.make_config(
        options.cell, n_features=data.features.shape[1], n_classes=n_classes, hidden_size=options.hidden_size,
        prior_layer=options.method == "priorlayer", smoothing=options.smoothing,
    )
    device = resolve_device(options.device)
    folds = folding.resolve(options.folds, options.mode, options.select, data.episodes, data.splits, workdir)
    trained = fit(data, config, options, device, progress)

    checkpoint_config = {
        "method": options.method,
        "mode": options.mode,
        "prior": options.prior if options.method == "priorlayer" else None,
        "seed": options.seed,
        "model": config.to_dict(),
        "features": list(meta["features"]),
        "classes": list(meta["classes"]),
        "source": meta.get("source", ""),
        "mean": trained.mean.tolist(),
        "std": trained.std.tolist(),
        "options": asdict(options),
        "kept_epoch": trained.kept_epoch,
        "n_train_units": trained.n_train_units,
        "n_val_units": trained.n_val_units,
        "val_spans": [list(span) for span in trained.val_spans],
        "inputs": {path.name: artifacts.file_digest(path) for path in inputs},
    }
    out_of_fold = None
    if folds is not None:
        checkpoint_config["folds"] = folds.record()
        out_of_fold, fold_inputs = fold_networks(workdir, data, config, options, folds, device, meta)
        trained.warnings.extend(out_of_fold[1])
    log_path = artifacts.train_log_path(workdir, options.method)
    checkpoint = artifacts.checkpoint_path(workdir, options.method)
    oof_path = artifacts.out_of_fold_path(workdir, options.method)
    with artifacts.atomic_path(checkpoint) as staged:  # all or none: a failed write keeps the old model
        save_checkpoint(staged, trained.model, checkpoint_config)
        artifacts.write_table(trained.log, log_path, "train_log",
                              {"options": asdict(options), "kept_epoch": trained.kept_epoch}, inputs=inputs)
        if out_of_fold is not None:
            table = folding.out_of_fold_table(frames.select("episode", "frame"), folds, out_of_fold[0])
            artifacts.write_table(table, oof_path, "out_of_fold",
                                  {"method": options.method, "options": asdict(options), "folds": folds.record(),
                                   "classes": list(meta["classes"]), "warnings": out_of_fold[1]},
                                  inputs=inputs + fold_inputs)
        else:
            oof_path.unlink(missing_ok=True)  # a network trained without folds has no out-of-fold predictions
    return TrainResult(checkpoint, log_path, trained, str(device))


def fold_networks(workdir: Path, data: FrameData, config: Any, options: TrainOptions, folds: Any,
                  device: torch.device, meta: dict[str, Any]) -> tuple[tuple[np.ndarray, list[str]], list[Path]]:
    """Train one network per fold without it and predict that fold: the out-of-fold class log-probabilities
    [n, C] of every training frame, the warnings, and the inputs read (PriorLayer's fold networks read their
    fold's MLN weights)."""
    fold_scores, inputs = None, []
    if options.method == "priorlayer":
        fold_scores, inputs = folding.fold_mln_scores(workdir, folds, list(meta["classes"]))
    out = np.zeros((len(data.labels), config.n_classes), dtype=np.float32)
    warnings = folding.missing_classes(folds, data.labels, list(meta["classes"]))
    for k in range(folds.k):
        prior = None if fold_scores is None else prior_input(fold_scores[k], options.prior, meta.get("source", ""))
        fold_data = replace(data, splits=folds.splits(k), prior=prior)
        trained = fit(fold_data, config, replace(options, select="none"), device, every_epoch=False)
        parts = fold_data.splits
        spans = [s for s in sequences.sequences(options.mode, data.episodes, parts, data.labels)
                 if parts[s.start] == "heldout"]
        features = ((data.features - trained.mean) / trained.std).astype(np.float32)
        log_probs = predict_log_probs(trained.model.to(device), spans, features, prior, device)
        held = folds.fold == k
        out[held] = log_probs[held]
    return (out, warnings), inputs
