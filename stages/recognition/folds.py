"""Folds of the training split for cross-validation: whole episodes when the split has at least K of them,
else K contiguous blocks of its frames (in file order). The assignment depends only on the frames' episodes
and splits and on K, so train (the fold networks), learn-weights (each fold's MLN weights) and conflate (the
out-of-fold decoding) cut the same folds; every artifact made from them records them."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.parts import Part

MIN_BLOCK_FRAMES = 20  # a block fold holds at least this many frames: shorter chains say little


@dataclass(frozen=True)
class Folds:
    fold: np.ndarray  # [n] fold of each training row, -1 on test rows
    kind: str  # episodes | blocks

    @property
    def k(self) -> int:
        return int(self.fold.max()) + 1

    def record(self) -> dict:
        """The assignment as metadata: K, the kind and each fold's row spans."""
        from mlnseq.timeline import sequences

        spans = [[s.start, s.stop] for s in sequences.runs(self.fold) if self.fold[s.start] >= 0]
        return {"k": self.k, "kind": self.kind, "spans": spans}

    def describe(self) -> str:
        """What was cut, for summaries: ``4 folds by episode`` or ``5 folds by block``."""
        return describe(self.record())

    def splits(self, k: int) -> np.ndarray:
        """The splits with fold ``k``'s rows marked ``heldout``: what a fold's network and MLN are fitted without."""
        return np.where(self.fold == k, Part.HELDOUT, np.where(self.fold >= 0, Part.TRAIN, Part.TEST))


def describe(record: dict) -> str:
    """A recorded assignment (Folds.record) in words: ``4 folds by episode`` or ``5 folds by block``."""
    return f"{record['k']} folds by {'episode' if record['kind'] == 'episodes' else 'block'}"


def largest(episodes: np.ndarray, splits: np.ndarray) -> int:
    """The largest K the training split allows: its episodes, or its blocks of MIN_BLOCK_FRAMES frames."""
    train = np.asarray(splits) == Part.TRAIN
    return max(len(np.unique(np.asarray(episodes)[train])), int(train.sum()) // MIN_BLOCK_FRAMES)


def suggested(episodes: np.ndarray, splits: np.ndarray, most: int = 5) -> int:
    """A K for a user's recogniser: whole episodes when the training split has at least 2 (up to ``most`` folds),
    else blocks (up to ``most``), else 0 (too small for folds)."""
    train = np.asarray(splits) == "train"
    n_episodes = len(np.unique(np.asarray(episodes)[train]))
    if n_episodes >= 2:
        return min(most, n_episodes)
    k = min(most, largest(episodes, splits))
    return k if k >= 2 else 0


def assign(episodes: np.ndarray, splits: np.ndarray, k: int, option: str = "--folds") -> Folds:
    """Cut the training rows into ``k`` folds (deterministic); refuse a K the split cannot make."""
    episodes, train = np.asarray(episodes), np.asarray(splits) == Part.TRAIN
    most = largest(episodes, splits)
    if k < 2 or k > most:
        good = suggested(episodes, splits)
        n_episodes = len(np.unique(episodes[train]))
        raise BadInput(f"{option} {k}: cross-validation needs at least 2 folds and this training split allows at "
                       f"most {most}; use {option} {good} ({good} folds by "
                       f"{'episode' if n_episodes >= good else 'block'}, as `mlnseq fit` cuts)" if most >= 2 else
                       f"{option} {k}: this training split is too small for 2 folds; use {option} 0")
    rows = np.flatnonzero(train)
    fold = np.full(len(episodes), -1, dtype=np.int64)
    present = list(dict.fromkeys(episodes[rows].tolist()))
    if len(present) >= k:
        for index, group in enumerate(np.array_split(np.arange(len(present)), k)):
            fold[rows[np.isin(episodes[rows], [present[i] for i in group])]] = index
        return Folds(fold, "episodes")
    for index, block in enumerate(np.array_split(rows, k)):
        fold[block] = index
    return Folds(fold, "blocks")


def resolve(k: int | None, mode: str, select: str, episodes: np.ndarray, splits: np.ndarray,
            workdir: Path | None = None) -> Folds | None:
    """``train --folds``: None is the default: in stream mode without a validation part, the folds the MLN's
    weights were learned on (weights.folds.parquet, from `learn-weights --folds K`), else none; 0 is none."""
    if k is None:
        path = None if workdir is None else Path(workdir) / artifacts.FOLD_WEIGHTS
        if mode != "stream" or select != "none" or path is None or not path.exists():
            return None
        k = int(artifacts.read_metadata(path, "fold_weights")["folds"]["k"])
    if k == 0:
        return None
    return assign(episodes, splits, k)


def same(recorded: dict, folds: Folds, what: str, remedy: str) -> None:
    """Refuse an artifact whose recorded folds differ from ``folds``."""
    if recorded != folds.record():
        raise BadInput(f"{what} was made with other folds ({recorded.get('k')} {recorded.get('kind')}) than "
                       f"{folds.k} {folds.kind}; rerun {remedy}")


def missing_classes(folds: Folds, labels: np.ndarray, classes: list[str]) -> list[str]:
    """A warning per fold whose fit part lacks a class the training split has."""
    train = folds.fold >= 0
    warnings = []
    for k in range(folds.k):
        missing = sorted(set(labels[train].tolist()) - set(labels[train & (folds.fold != k)].tolist()))
        if missing:
            warnings.append(f"fold {k}: its fit part lacks class{'es' if len(missing) > 1 else ''} "
                            f"{', '.join(classes[c] for c in missing)}; its out-of-fold predictions are written "
                            "all the same")
    return warnings


def out_of_fold_table(keys: pl.DataFrame, folds: Folds, log_probs: np.ndarray) -> pl.DataFrame:
    """The training rows' keys (episode, frame), fold and out-of-fold class log-probabilities (lp0..)."""
    rows = folds.fold >= 0
    table = keys.filter(pl.Series(rows)).with_columns(pl.Series("fold", folds.fold[rows], dtype=pl.Int16))
    return table.with_columns([pl.Series(name, log_probs[rows, c], dtype=pl.Float32)
                               for c, name in enumerate(artifacts.log_prob_columns(log_probs.shape[1]))])


def fold_mln_scores(workdir: Path, folds: Folds, classes: Sequence[str]) -> tuple[list[np.ndarray], list[Path]]:
    """Each fold's per-frame MLN class scores, from weights.folds.parquet (checked to hold the same folds)."""
    from mlnseq.mln import classifier

    weights, path = fold_weights(workdir, folds)
    predicates, _ = artifacts.read_table(Path(workdir) / artifacts.PREDICATES, "predicates")
    return [classifier.class_scores(predicates, w, classes) for w in weights], [path]


def fold_weights(workdir: Path, folds: Folds) -> tuple[list[pl.DataFrame], Path]:
    """Each fold's MLN weights table (weights.folds.parquet), refused when made with other folds."""
    path = Path(workdir) / artifacts.FOLD_WEIGHTS
    if not path.exists():
        raise BadInput(f"{path} not found: cross-validation reads each fold's MLN weights; run "
                       f"`mlnseq learn-weights --folds {folds.k}` first (or train with --folds 0)")
    table, meta = artifacts.read_table(path, "fold_weights")
    same(meta["folds"], folds, str(path), f"`mlnseq learn-weights --folds {folds.k}`")
    return [table.filter(pl.col("fold") == k).drop("fold") for k in range(folds.k)], path
