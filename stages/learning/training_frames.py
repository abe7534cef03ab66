"""The frames the predicate search reads (mlnseq.learning.learned_logic): the training split cut into the folds `mlnseq
fit` cuts, and where it holds more than ``SEARCH_FRAMES`` frames, whole episodes drawn evenly from each fold (every
fold keeps its share, at least one episode), so that the search's cost stops growing with the recordings."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from mlnseq.choosing import folds as folding
from mlnseq.learning.candidates import Frames
from mlnseq.learning.quick_chain import Split
from mlnseq.mln.chain import chain_starts

SEARCH_FRAMES = 4_000  # training frames the search reads at most (whole episodes, from every fold)


@dataclass(frozen=True)
class Training:
    """The frames as the search reads them (episodes in order) and the folds."""

    frames: Frames
    split: Split  # the training rows only
    rows: np.ndarray  # the training rows' indices into the frames
    episodes: np.ndarray
    folds: folding.Folds
    table: pl.DataFrame  # the frames searched: the training split's, or the episodes drawn from it
    record: dict  # the folds as `mlnseq fit` cuts the whole training split (Folds.record)
    sampled: tuple[int, int] | None = None  # (episodes drawn, training episodes), where drawn


def training(frames: pl.DataFrame, n_classes: int, most: int = SEARCH_FRAMES) -> Training | None:
    """The search's view of ``frames`` (sorted by episode and frame), its training split cut into folds as `mlnseq
    fit` cuts them, and beyond ``most`` training frames only the episodes ``drawn``: None when the training split is
    too small for 2 folds."""
    episodes, splits = frames["episode"].to_numpy(), frames["split"].to_numpy()
    labels = frames["label"].to_numpy().astype(np.int64)
    k = folding.suggested(episodes, splits)
    if not k:
        return None
    whole = folding.assign(episodes, splits, labels, k)
    kept, sampled = drawn(whole, episodes, most)
    frames, episodes, labels = frames[kept], episodes[kept], labels[kept]
    folds = folding.Folds(whole.fold[kept], whole.kind, whole.cut)
    view = Frames(folds.fold >= 0, labels, chain_starts(episodes), folds.fold, n_classes)
    rows = np.flatnonzero(folds.fold >= 0)
    split = Split(labels[rows], chain_starts(episodes, folds.fold, rows=rows), folds.fold[rows], episodes[rows],
                  n_classes)
    return Training(view, split, rows, episodes, folds, frames, whole.record(), sampled)


def drawn(folds: folding.Folds, episodes: np.ndarray, most: int) -> tuple[np.ndarray, tuple[int, int] | None]:
    """The rows the search reads: every row where the training split has at most ``most``, else whole training
    episodes spread evenly over each fold's, each fold its share of ``most`` (at least one episode); and (episodes
    drawn, training episodes) where some were left out."""
    train = np.flatnonzero(folds.fold >= 0)
    if len(train) <= most:
        return np.arange(len(folds.fold)), None
    kept, drawn_episodes, total = [], 0, 0
    for k in range(folds.k):
        rows = np.flatnonzero(folds.fold == k)
        names, first, sizes = np.unique(episodes[rows], return_index=True, return_counts=True)
        order = np.argsort(first)  # episodes as they come
        names, sizes = names[order], sizes[order]
        share = max(1, min(len(names), len(names) * most // len(train)))
        chosen = names[np.unique(np.linspace(0, len(names) - 1, share).round().astype(np.int64))]
        kept.append(rows[np.isin(episodes[rows], chosen)])
        drawn_episodes, total = drawn_episodes + len(chosen), total + len(names)
    return np.sort(np.concatenate(kept)), (drawn_episodes, total)
