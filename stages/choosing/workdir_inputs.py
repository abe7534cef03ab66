"""A workdir's trained pieces as arrays: its frames, the MLN's class scores and evidence, and every trained
network's class log-probabilities over all frames. What conflate, export and train read, in one place."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.timeline import sequences
from mlnseq.model.checkpoints import Checkpoint, checkpoint_config, load_checkpoint
from mlnseq.model.log_prob_cache import cached_log_probs
from mlnseq.catalog.errors import BadInput, StaleArtifact
from mlnseq.choosing.folds import Folds
from mlnseq.catalog.methods import NETWORKS, Method, PaperFloor
from mlnseq.catalog.notes import MISSING_INPUT, Note
from mlnseq.catalog.parts import Part


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


def mln_class_scores(workdir: Path, frames: pl.DataFrame, classes: Sequence[str]) -> tuple[np.ndarray, list[Path]]:
    """Per-frame summed MLN formula weights per class, from predicates.parquet and weights.parquet."""
    from mlnseq.mln import classifier

    predicates, weights, inputs = read_mln(workdir, frames)
    return classifier.class_scores(predicates, weights, classes), inputs


def parts_of(config: dict[str, Any], splits: np.ndarray) -> np.ndarray:
    """Per row: test, val (the checkpoint's validation part, held out of fitting) or train."""
    parts = np.where(splits == Part.TEST, Part.TEST, Part.TRAIN).astype(object)
    for start, stop in config.get("val_spans", []):
        parts[start:stop] = Part.VAL
    return parts.astype(str)


@dataclass(frozen=True)
class MLNInputs:
    """The MLN over the workdir's frames: its weights, per-frame class scores and evidence (predicate values)."""

    weights: pl.DataFrame
    scores: np.ndarray  # [n, C] summed per-frame formula weights
    columns: list[str]  # predicate columns, in evidence order
    evidence: np.ndarray  # bool [n, W]
    predicates: pl.DataFrame | None = None


@dataclass(frozen=True)
class TrainedNetwork:
    """A trained network and its class log-probabilities over every frame (its state reset as in training: per
    segment or per block)."""

    checkpoint: Checkpoint
    parts: np.ndarray  # [n] test | val | train
    log_probs: np.ndarray  # [n, C]


@dataclass(frozen=True)
class FoldInputs:
    """Cross-validation: the folds, each network's out-of-fold log-probabilities (training rows; 0 on test) and
    each fold's MLN (weights learned without it)."""

    folds: Folds
    log_probs: dict[str, np.ndarray]  # network -> [n, C]
    mln: list[MLNInputs]  # per fold; empty without weights.parquet


@dataclass
class WorkdirInputs:
    keys: pl.DataFrame
    data: FrameData
    meta: dict[str, Any]  # frames.parquet's metadata
    mln: MLNInputs | None
    networks: dict[Method, TrainedNetwork]
    inputs: list[Path]
    paper_floor: PaperFloor  # how the MLN's class sums are floored (mln-mode paper, PriorLayer's paper input)
    notes: list[Note] = field(default_factory=list)
    folds: FoldInputs | None = None

    @property
    def classes(self) -> list[str]:
        return list(self.meta["classes"])


def paper_floor(workdir: Path, frames_meta: dict[str, Any]) -> PaperFloor:
    """The floor of the MLN's class sums that the workdir's networks were trained with (they must agree), else the
    dataset's (PaperFloor.for_recordings; also for a checkpoint written before networks recorded it)."""
    default = PaperFloor.for_recordings(frames_meta.get("source", ""))
    floors = {PaperFloor(checkpoint_config(workdir, n).get("paper_floor") or default)
              for n in NETWORKS if artifacts.checkpoint_path(workdir, n).exists()}
    if len(floors) > 1:
        raise BadInput(f"the networks in {workdir / 'models'} were trained with different --paper-floor "
                       f"({', '.join(sorted(floors))}); train them again with the same")
    return floors.pop() if floors else default


def read_workdir(workdir: Path, networks: Sequence[str]) -> WorkdirInputs:
    """Frames, the MLN (when weights.parquet exists) and each of ``networks`` that is trained, run over all
    frames; what is absent is left out with a note. PriorLayer needs the MLN for its input."""
    from mlnseq.fusion.fuse import prior_input

    workdir = Path(workdir)
    frames_path = workdir / artifacts.FRAMES
    frames, meta = artifacts.read_table(frames_path, "frames")
    frames = artifacts.labelled(frames)
    data = FrameData.from_frames(frames)
    floor = paper_floor(workdir, meta)
    result = WorkdirInputs(frames.select(artifacts.KEY_COLUMNS), data, meta, None, {}, [frames_path], floor)
    result.mln = _read_mln(workdir, frames, result)
    for network in map(Method, networks):
        path = artifacts.checkpoint_path(workdir, network)
        if not path.exists():
            result.notes.append(Note(MISSING_INPUT, f"no {network} model: {network} left out "
                                                    f"(run `mlnseq train --method {network}`)"))
            continue
        checkpoint = load_checkpoint(workdir, network, meta)
        result.inputs.append(path)
        if network == Method.PRIORLAYER and result.mln is None:
            continue
        prior = None if network == Method.NETWORK else prior_input(result.mln.scores, checkpoint.config["prior"],
                                                                   floor)
        parts = parts_of(checkpoint.config, data.splits)
        spans = sequences.sequences(checkpoint.mode, data.episodes, parts, data.labels)
        log_probs = cached_log_probs(path, frames_path, prior,
                                     partial(checkpoint.network.log_probs, spans, data.features, prior))
        result.networks[network] = TrainedNetwork(checkpoint, parts, log_probs)
    result.folds = read_folds(workdir, result)
    return result


def _read_mln(workdir: Path, frames: pl.DataFrame, result: WorkdirInputs) -> MLNInputs | None:
    """The MLN over the frames when weights.parquet exists (its inputs added to ``result``'s), else a note."""
    from mlnseq.mln import classifier

    if not (workdir / artifacts.WEIGHTS).exists():
        result.notes.append(Note(MISSING_INPUT, f"no {artifacts.WEIGHTS}: mln, priorlayer, conflation and combined "
                                                "left out (run `mlnseq learn-weights`)"))
        return None
    predicates, weights, mln_inputs = read_mln(workdir, frames)
    result.inputs += mln_inputs
    columns = artifacts.feature_columns(predicates)
    return MLNInputs(weights, classifier.class_scores(predicates, weights, result.classes), columns,
                     predicates.select(columns).to_numpy().astype(bool), predicates)


def read_folds(workdir: Path, inputs: WorkdirInputs) -> FoldInputs | None:
    """The out-of-fold predictions of the networks trained with folds, and each fold's MLN; None when no network
    was. Networks with other folds than each other, or an out-of-fold file that is not its checkpoint's, are refused."""
    from mlnseq.choosing import folds as folding
    from mlnseq.mln import classifier

    folded = {n: r for n, r in inputs.networks.items() if r.checkpoint.config.get("folds")}
    if not folded:
        return None
    records = {n: r.checkpoint.config["folds"] for n, r in folded.items()}
    if len({str(r) for r in records.values()}) > 1:
        raise BadInput(f"the networks were trained with different folds ({records}); retrain them with the same "
                       "`train --folds K`")
    first = next(iter(records.values()))
    folds = folding.assign(inputs.data.episodes, inputs.data.splits, inputs.data.labels, first["k"])
    log_probs = {}
    train = folds.fold >= 0
    for network, trained in folded.items():
        folding.same(records[network], folds, str(artifacts.checkpoint_path(workdir, network)),
                     f"`mlnseq train --method {network} --folds {first['k']}`")
        path = artifacts.out_of_fold_path(workdir, network)
        remedy = f"rerun `mlnseq train --method {network} --folds {first['k']}`"
        if not path.exists():
            raise BadInput(f"{path} not found, though {network} was trained with folds; {remedy}")
        table, meta = artifacts.read_table(path, "out_of_fold")
        if meta.get("options") != trained.checkpoint.config["options"] or table.height != int(train.sum()):
            raise StaleArtifact(f"{path} is not the out-of-fold predictions of models/{network}.pt; {remedy}")
        values = np.zeros_like(trained.log_probs)
        values[train] = table.select(artifacts.log_prob_columns(values.shape[1])).to_numpy()
        log_probs[network] = values
        inputs.inputs.append(path)
    mln = []
    if inputs.mln is not None:
        weights, path = folding.fold_weights(workdir, folds)
        tables, read = folding.fold_predicates(workdir, folds, inputs.mln.predicates,
                                               artifacts.read_metadata(workdir / artifacts.PREDICATES))
        inputs.inputs += [path, *read]
        for w, table in zip(weights, tables):  # a fold's MLN scores only training frames (never test)
            scores = np.zeros_like(inputs.mln.scores)
            scores[train] = classifier.class_scores(table.filter(pl.Series(train)), w, inputs.classes)
            columns = artifacts.feature_columns(table)
            mln.append(MLNInputs(w, scores, columns, table.select(columns).to_numpy().astype(bool)))
    return FoldInputs(folds, log_probs, mln)
