"""train: fit a network (LSTM, GRU or causal TCN: stages/networks/), alone or with the MLN PriorLayer, on the
training split.

The core (:func:`fit`) works on arrays; :func:`run` reads ``frames.parquet`` (and, for PriorLayer,
``predicates.parquet`` + ``weights.parquet``), writes ``models/<method>.pt`` and its per-epoch log;
:func:`run_seeds` does so for the seed workdirs of one dataset, their networks fitted side by side.

Validation part: with ``select="last"`` or ``"val_accuracy"`` the last ``val_fraction`` of the training
units (segments in segment mode, windows in stream mode, in file order) is held out of training and scored
each epoch; the checkpoint records it, and conflate chooses its weights on it. ``last`` keeps the last
epoch, ``val_accuracy`` the epoch with the best frame accuracy on that part. With ``none`` every training
unit is used and the last epoch is kept. The test split is only ever logged (for the curves), never used.
The parts' accuracy and loss are measured (a pass over every frame) and logged after every epoch with
``measure="every-epoch"`` (the curves; ``select="val_accuracy"`` needs them), else after the last only.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from enum import Enum, StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from mlnseq import networks
from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput, check_choice
from mlnseq.catalog.methods import ALIASES, NETWORKS, PRIORS, Method, PaperFloor, Prior, member
from mlnseq.catalog.parts import Part
from mlnseq.model.checkpoints import write_checkpoint
from mlnseq.networks.fitting import Fitting, Schedule, predict_log_probs, resolve_device, set_threads
from mlnseq.networks.updates import Optimizer, Training, member_seeds
from mlnseq.choosing.training_rows import Rows, Select, assign_parts
from mlnseq.choosing import folds as folding
from mlnseq.choosing import fold_networks as fold_networks_of
from mlnseq.fusion.fuse import prior_input
from mlnseq.choosing.workdir_inputs import FrameData, mln_class_scores
from mlnseq.timeline import sequences

if TYPE_CHECKING:  # torch loads only when a network is built or run
    import torch

    from mlnseq.networks.classifier import SequenceClassifier


class Measure(StrEnum):
    """After which epochs fit measures the parts (train, val, test) over all their frames and logs them."""

    EVERY_EPOCH = "every-epoch"  # the per-epoch curves (the report's figures); what --select val_accuracy reads
    LAST_EPOCH = "last-epoch"  # the kept network's only (the default without --select val_accuracy)


METHODS = NETWORKS
SELECTS = tuple(Select)
DEVICES = ("auto", "cpu", "cuda")


@dataclass(frozen=True)
class TrainOptions:
    """Options of `mlnseq train`."""

    method: Method = Method.NETWORK  # the network alone (``network``, or ``lstm``) or priorlayer
    seed: int = 0
    epochs: int = 100
    mode: str = "segment"
    cell: str = "lstm"  # the network type: a name in mlnseq.networks.TYPES
    prior: Prior = Prior.PAPER  # c2c input of PriorLayer: paper (floored MLN sums) | logprob (MLN log-probs)
    select: Select = Select.NONE
    measure: Measure | None = None  # None: every-epoch with select val_accuracy, else last-epoch
    device: str = "auto"
    train_fraction: float = 1.0
    batch_size: int = 4
    window: int = 64  # stream mode: training window length in frames
    hidden_size: int = 32
    learning_rate: float | None = None  # None: the optimizer's own (sgd 0.1, adam 3e-3)
    optimizer: Optimizer = Optimizer.SGD  # sgd: the authors' (the reproduction's); adam: settles (networks/updates.py)
    updates: int = 0  # adam: at most this many updates (0: epochs alone decide)
    members: int = 1  # networks fitted per seed, side by side, and averaged into the one kept (classifier.merged)
    val_fraction: float = 0.2
    smoothing: float = 0.0  # tcn: weight of MS-TCN's smoothing loss
    folds: int | None = None  # cross-validation folds (choosing/folds.py); None: stream mode's default, 0: none
    paper_floor: PaperFloor | None = None  # the MLN sums' floor (PaperFloor); None: the dataset's

    def __post_init__(self) -> None:
        for name, kind, aliases in (("method", Method, ALIASES), ("prior", Prior, None), ("select", Select, None),
                                    ("measure", Measure, None), ("paper_floor", PaperFloor, None),
                                    ("optimizer", Optimizer, None)):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, member(kind, getattr(self, name), aliases))

    def validate(self) -> None:
        check_choice("method", self.method, (*ALIASES, *METHODS))
        choices = {"mode": sequences.MODES, "cell": networks.CELLS, "prior": PRIORS, "select": SELECTS,
                   "device": DEVICES, "optimizer": tuple(Optimizer)}
        for name, allowed in choices.items():
            check_choice(name, getattr(self, name), allowed)
        if self.paper_floor is not None:
            check_choice("paper-floor", self.paper_floor, tuple(PaperFloor))
        if self.measure is not None:
            check_choice("measure", self.measure, tuple(Measure))
        if self.select == Select.VAL_ACCURACY and self.measure == Measure.LAST_EPOCH:
            raise BadInput("--select val_accuracy compares every epoch: use --measure every-epoch (or leave it out)")
        self._check_numbers()
        if self.device == "cuda":
            import torch

            if not torch.cuda.is_available():
                raise BadInput("--device cuda: no CUDA GPU is visible to torch here; use --device cpu")

    def _check_numbers(self) -> None:
        if not 0 < self.train_fraction <= 1:
            raise BadInput(f"--train-fraction must be in (0, 1], got {self.train_fraction}")
        if not 0 < self.val_fraction < 1:
            raise BadInput(f"--val-fraction must be in (0, 1), got {self.val_fraction}")
        for name in ("epochs", "batch_size", "window", "hidden_size", "members"):
            if getattr(self, name) < 1:
                raise BadInput(f"--{name.replace('_', '-')} must be at least 1, got {getattr(self, name)}")
        if self.smoothing < 0:
            raise BadInput(f"--smoothing must be at least 0, got {self.smoothing}")
        if self.folds is not None and self.folds < 0:
            raise BadInput(f"--folds {self.folds}: use 0 (no folds) or at least 2 folds")
        if self.learning_rate is not None and not self.learning_rate > 0:
            raise BadInput(f"--learning-rate must be positive, got {self.learning_rate}")
        if self.updates < 0:
            raise BadInput(f"--updates must be at least 0 (0: no cap), got {self.updates}")

    @property
    def training(self) -> Training:
        """How the networks are fitted (networks/updates.py)."""
        return Training(self.optimizer, self.epochs, self.batch_size, self.learning_rate, self.updates)

    @property
    def measured(self) -> Measure:
        """After which epochs the parts are measured: ``measure``, else what ``select`` needs."""
        every = self.select == Select.VAL_ACCURACY
        return self.measure or (Measure.EVERY_EPOCH if every else Measure.LAST_EPOCH)

    def record(self) -> dict[str, Any]:
        """The options as artifacts store them: plain values (a checkpoint loads without our types); not ``measure``:
        the network does not depend on it, and the log's metadata says what it holds (``measured``)."""
        return {k: v.value if isinstance(v, Enum) else v for k, v in asdict(self).items() if k != "measure"}


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


@dataclass(frozen=True)
class EpochDone:
    """What :func:`fit` tells its progress callback after each epoch (frame accuracy and NLL of the parts)."""

    epoch: int
    epochs: int
    loss: float | None  # on the training sequences; None: not measured after this epoch (Measure)
    train_accuracy: float | None
    val_accuracy: float | None  # None without a validation part (--select none), or not measured


Progress = Callable[[EpochDone], None]
LOG_SCHEMA = {"epoch": pl.Int32, "split": pl.String, "accuracy": pl.Float64, "loss": pl.Float64}


def fit(data: FrameData, config: Any, options: TrainOptions, device: torch.device, progress: Progress | None = None,
        seeds: tuple[int, ...] | None = None, units: int | None = None, stop: list[int] | None = None) -> list[Trained]:
    """Train a network on the training split of ``data`` per seed (``options.seed``, or each of ``seeds``; each the
    mean of ``options.members`` networks; all side by side: fitting.Together); log train/val/test accuracy after every
    epoch (measure every-epoch) or the last; keep the last epoch (``stop``: each seed's, as its fold networks chose),
    or with ``select`` val_accuracy the one of best frame accuracy on the validation part. ``progress`` hears the first
    seed's; ``units``: the fit units Adam's budget is of (None: this network's)."""
    from mlnseq.networks.classifier import merged

    rows = Rows.of(data, options)
    seeds = seeds or (options.seed,)
    members = [[rows.start(data, config, replace(options, seed=m), device) for m in member_seeds(seed, options.members)]
               for seed in seeds]
    schedule = Schedule([m for per_seed in members for m in per_seed], options.training, units or len(rows.fit_units))
    last = stop or [schedule.epochs] * len(seeds)
    logs: list[list[dict[str, Any]]] = [[] for _ in seeds]
    best: list[tuple[Any, float, int]] = [(None, -1.0, end) for end in last]  # (model, val accuracy, epoch) kept
    every_epoch = options.measured == Measure.EVERY_EPOCH
    for epoch in range(1, max(last) + 1):
        schedule.epoch()
        if every_epoch or epoch in last:
            schedule.write_back()
        for i, per_seed in enumerate(members):
            if epoch > last[i]:
                continue
            model = merged([m.model for m in per_seed]).to(device) if every_epoch or epoch == last[i] else None
            measured = {} if model is None else rows.measure(Fitting(model, (), None, device), data, options.mode)
            logs[i] += [{"epoch": epoch, "split": str(name), "accuracy": accuracy, "loss": nll}
                        for name, (accuracy, nll) in measured.items()]
            if progress is not None and i == 0:
                train, val = measured.get(Part.TRAIN, (None, None)), measured.get(Part.VAL)
                progress(EpochDone(epoch, last[0], train[1], train[0], None if val is None else val[0]))
            if options.select != Select.VAL_ACCURACY:
                best[i] = (model, -1.0, epoch) if epoch == last[i] else best[i]
            elif measured[Part.VAL][0] > best[i][1]:
                best[i] = (model, measured[Part.VAL][0], epoch)
    trained, warnings = [], rows.warnings(data)
    val_spans = [(u.start, u.stop) for u in rows.val_units]
    for (model, _, kept_epoch), log in zip(best, logs):
        trained.append(Trained(model.cpu(), rows.mean, rows.std, pl.DataFrame(log, schema=LOG_SCHEMA), kept_epoch,
                               len(rows.fit_units), len(rows.val_units), list(val_spans), list(warnings)))
    return trained


# --- the stage ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrainResult:
    checkpoint: Path
    log: Path
    trained: Trained
    device: str


@dataclass(frozen=True)
class OutOfFold:
    """The fold networks' predictions: each training frame's class log-probabilities [n, C] by the network
    trained without its fold, the warnings, and the inputs read (PriorLayer's fold networks read their fold's
    MLN weights)."""

    log_probs: np.ndarray
    warnings: list[str]
    inputs: list[Path]


def run(workdir: Path, options: TrainOptions, progress: Progress | None = None) -> TrainResult:
    """Train on ``workdir/frames.parquet``; write ``models/<method>.pt`` and ``models/<method>.log.parquet``."""
    return run_seeds([Path(workdir)], (options.seed,), options, progress)[0]


def run_seeds(workdirs: list[Path], seeds: tuple[int, ...], options: TrainOptions,
              progress: Progress | None = None) -> list[TrainResult]:
    """:func:`run` for each workdir with its seed, the networks fitted side by side; the workdirs hold the same
    inputs (the seed workdirs of one dataset)."""
    options.validate()
    if len(workdirs) != len(seeds) or len(set(seeds)) != len(seeds):
        raise BadInput(f"train: {len(seeds)} --seed and {len(workdirs)} --workdir: give one distinct seed per workdir")
    set_threads()
    loaded = [_read_inputs(Path(workdir), options) for workdir in workdirs]
    frames, meta, data, inputs, options = loaded[0]
    digests = [artifacts.file_digest(path) for path in inputs] if len(loaded) > 1 else []  # a lone run compares none
    for workdir, other in zip(workdirs[1:], loaded[1:]):
        if [artifacts.file_digest(path) for path in other[3]] != digests:
            raise BadInput(f"{workdir}: its inputs differ from {workdirs[0]}'s; networks trained side by side share "
                           "their rows: train it in a run of its own")
    config = networks.make_config(
        options.cell, n_features=data.features.shape[1], n_classes=len(meta["classes"]),
        hidden_size=options.hidden_size, prior_layer=options.method == Method.PRIORLAYER, smoothing=options.smoothing,
    )
    folds = [folding.resolve(options.folds, options.mode, options.select, data.episodes, data.splits,
                             data.labels, Path(workdir))
             for workdir in workdirs]  # before any epoch: --folds the training split cannot cut is refused at once
    device = resolve_device(options.device)
    units = len(assign_parts(data, replace(options, select=Select.NONE))[1])  # Adam's budget: the training split's
    out_of_fold: list[OutOfFold | None] = [None] * len(workdirs)
    stop = None
    settled = options.optimizer != Optimizer.SGD  # Adam: the folds first, to say when the network stops
    if folds[0] is not None:
        for workdir, other in zip(workdirs[1:], folds[1:]):
            if other is None or other.record() != folds[0].record():
                raise BadInput(f"{workdir}: its folds differ from {workdirs[0]}'s: train it in a run of its own")
        if settled:
            out_of_fold, stop = fold_networks(workdirs, data, config, options, folds[0], device, meta, seeds, units)
    trained = fit(data, config, options, device, progress, seeds, units, stop)
    if folds[0] is not None and not settled:
        out_of_fold, _ = fold_networks(workdirs, data, config, options, folds[0], device, meta, seeds, units)
    results = []
    for workdir, seed, one, oof in zip(workdirs, seeds, trained, out_of_fold):
        workdir, seeded = Path(workdir), replace(options, seed=seed)
        checkpoint_config = _checkpoint_config(seeded, one.model.config, meta, one, inputs)
        if oof is not None:
            checkpoint_config["folds"] = folds[0].record()
            one.warnings.extend(oof.warnings)
        paths = _write(workdir, seeded, one, checkpoint_config, inputs, frames, meta, folds[0], oof)
        results.append(TrainResult(paths[0], paths[1], one, str(device)))
    return results


def _read_inputs(workdir: Path, options: TrainOptions) -> tuple[pl.DataFrame, dict, FrameData, list[Path],
                                                                 TrainOptions]:
    """A workdir's frames, their metadata, the rows a network fits (with PriorLayer's MLN input), the files read,
    and the options with the recordings' paper floor."""
    frames_path = workdir / artifacts.FRAMES
    frames, meta = artifacts.read_table(frames_path, "frames")
    frames = artifacts.labelled(frames)
    options = replace(options, paper_floor=options.paper_floor or PaperFloor.for_recordings(meta.get("source", "")))
    inputs = [frames_path]
    prior = None
    if options.method == Method.PRIORLAYER:
        scores, mln_inputs = mln_class_scores(workdir, frames, meta["classes"])
        prior = prior_input(scores, options.prior, options.paper_floor)
        inputs += mln_inputs
    return frames, meta, FrameData.from_frames(frames, prior), inputs, options


def _checkpoint_config(options: TrainOptions, config: Any, meta: dict[str, Any], trained: Trained,
                       inputs: list[Path]) -> dict[str, Any]:
    """What a checkpoint embeds beside the state dict: the network's configuration and how it was trained."""
    return {
        "method": str(options.method),
        "mode": options.mode,
        "prior": str(options.prior) if options.method == Method.PRIORLAYER else None,
        "paper_floor": str(options.paper_floor),
        "seed": options.seed,
        "model": config.to_dict(),
        "features": list(meta["features"]),
        "classes": list(meta["classes"]),
        "source": meta.get("source", ""),
        "mean": trained.mean.tolist(),
        "std": trained.std.tolist(),
        "options": options.record(),
        "kept_epoch": trained.kept_epoch,
        "n_train_units": trained.n_train_units,
        "n_val_units": trained.n_val_units,
        "val_spans": [list(span) for span in trained.val_spans],
        "inputs": {path.name: artifacts.file_digest(path) for path in inputs},
    }


def _write(workdir: Path, options: TrainOptions, trained: Trained, checkpoint_config: dict[str, Any],
           inputs: list[Path], frames: pl.DataFrame, meta: dict[str, Any], folds: folding.Folds | None,
           out_of_fold: OutOfFold | None) -> tuple[Path, Path]:
    """Write the checkpoint, its log and its out-of-fold predictions, all or none: a failed write keeps the old."""
    log_path = artifacts.train_log_path(workdir, options.method)
    checkpoint = artifacts.checkpoint_path(workdir, options.method)
    oof_path = artifacts.out_of_fold_path(workdir, options.method)
    with artifacts.atomic_path(checkpoint) as staged:
        write_checkpoint(staged, trained.model, checkpoint_config)
        artifacts.write_table(trained.log, log_path, "train_log",
                              {"options": options.record(), "kept_epoch": trained.kept_epoch,
                               "measured": str(options.measured)}, inputs=inputs)
        if out_of_fold is not None:
            table = folding.out_of_fold_table(frames.select("episode", "frame"), folds, out_of_fold.log_probs)
            artifacts.write_table(table, oof_path, "out_of_fold",
                                  {"method": str(options.method), "options": options.record(),
                                   "folds": folds.record(), "classes": list(meta["classes"]),
                                   "warnings": out_of_fold.warnings},
                                  inputs=inputs + out_of_fold.inputs)
        else:
            oof_path.unlink(missing_ok=True)  # a network trained without folds has no out-of-fold predictions
    return checkpoint, log_path


def fold_networks(workdirs: list[Path], data: FrameData, config: Any, options: TrainOptions, folds: folding.Folds,
                  device: torch.device, meta: dict[str, Any], seeds: tuple[int, ...], units: int
                  ) -> tuple[list[OutOfFold], list[int] | None]:
    """Train one network per fold and seed without the fold, and predict that fold's rows: each workdir's out-of-fold
    predictions by the networks of its seed; and, with Adam, each seed's epoch chosen by them (fit_folds)."""
    classes = list(meta["classes"])
    fold_scores, inputs = None, [[] for _ in workdirs]
    if options.method == Method.PRIORLAYER:
        read = [folding.fold_mln_scores(workdir, folds, classes) for workdir in workdirs]
        fold_scores, inputs = read[0][0], [paths for _, paths in read]
        for workdir, (scores, _) in zip(workdirs[1:], read[1:]):
            if any(not np.array_equal(a, b) for a, b in zip(scores, fold_scores)):
                raise BadInput(f"{workdir}: its fold weights differ from {workdirs[0]}'s: train it in a run of its own")
    warnings = folding.missing_classes(folds, data.labels, classes)
    fold_data = [replace(data, splits=folds.splits(k), prior=None if fold_scores is None else
                         prior_input(fold_scores[k], options.prior, options.paper_floor)) for k in range(folds.k)]
    fitted, parts, stop = fold_networks_of.fit_folds(fold_data, config, options, device, seeds, units, folds)
    return [OutOfFold(fold_networks_of.out_of_fold(per_seed, parts, device), list(warnings), read_inputs)
            for per_seed, read_inputs in zip(fitted, inputs)], stop
