"""Exact inference on linear chains of frames: forward filtering, forward-backward, Viterbi, log Z.

A chain's distribution is p(y) = exp(sum_t unary[t, y_t] + sum_t pairwise[link[t], y_{t-1}, y_t]) / Z,
every frame with ``link[t] == -1`` starting a new chain (an episode's, or a block's, first frame).
All chains of a call are one long product of per-step matrices: a chain start is the matrix whose rows
all equal exp(unary[t]), so each chain's total is carried into the next and log Z is their sum.

Dead ends (a frame where no class is possible given the previous frames: hard rules contradict each
other or the previous state) restart the chain at that frame from its unary alone, without the
forbidding transition; a frame whose unary is -inf everywhere becomes uniform. ``Filter`` does this one
frame at a time; the batch functions find the same frames and then treat them as chain starts, so they
agree (``decode_filter`` and ``decode_viterbi`` also say which frames they were). Where the scan's block
products underflow although every frame stays possible (a chain the hard rules hold in a few states for
hundreds of frames, their probabilities far below e^-745 within a block), the forward pass runs frame by
frame instead, as ``Filter``.
The scan that computes them, one numpy call per level of a binary tree over the steps (about
2 log2 T calls in all), is stages/mln/chain_scan.py; the factors and the filter are
stages/mln/chain_factors.py; the moments only the CLL learner needs are stages/mln/chain_moments.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlnseq.mln.chain_factors import CLIP, ChainFactors, Filter, _restarted
from mlnseq.mln.chain_scan import Repeats, _Dead, _forward, _smoothed, _viterbi_once

__all__ = ["CLIP", "ChainFactors", "Decoded", "Filter", "chain_starts", "decode_filter", "decode_viterbi", "filtered",
           "log_partition", "path_score", "smoothed", "viterbi"]


def filtered(factors: ChainFactors) -> np.ndarray:
    """[T, C] log p(y_t | frames of its chain up to t) (online)."""
    if len(factors.link) == 0:
        return np.zeros((0, factors.n_classes))
    with np.errstate(divide="ignore"):
        return np.log(_forward(factors).alpha)


def smoothed(factors: ChainFactors) -> np.ndarray:
    """[T, C] log p(y_t | all frames of its chain) (forward-backward)."""
    if len(factors.link) == 0:
        return np.zeros((0, factors.n_classes))
    with np.errstate(divide="ignore"):
        return np.log(_smoothed(_forward(factors))[0])


def log_partition(factors: ChainFactors, repeats: Repeats | None = None) -> float:
    """Sum over chains of log Z (a chain cut by a dead end counts as its pieces); ``repeats``: where the chains' steps
    repeat (frames of one unary row and link), for many passes over the same chains."""
    if len(factors.link) == 0:
        return 0.0
    return _forward(factors, vectors=False, repeats=repeats).log_z


def viterbi(factors: ChainFactors) -> np.ndarray:
    """[T] int64 the most probable class path of each chain (ties: the lower class)."""
    if len(factors.link) == 0:
        return np.zeros(0, dtype=np.int64)
    try:
        return _viterbi_once(factors)
    except _Dead:
        return _viterbi_once(_restarted(factors))


@dataclass(frozen=True)
class Decoded:
    """A decoded chain, by any decoder (stages/fusion/decoding.py dispatches): class probabilities, the predicted
    classes and where a dead end restarted the chain."""

    probabilities: np.ndarray  # [T, C] filter: p(y_t | frames up to t); viterbi: p(y_t | all frames of its chain);
    # the lagged and posterior decoders (lag.py): their decision scores turned into probabilities
    path: np.ndarray  # [T] int64 filter: each frame's most probable class; viterbi: the most probable path
    restarts: np.ndarray  # [R] int64 the frames where no class was possible given the previous ones: a new chain

    @classmethod
    def empty(cls, n_classes: int) -> Decoded:
        return cls(np.zeros((0, n_classes)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))


def dead_ends(original: ChainFactors, restarted: ChainFactors) -> np.ndarray:
    """[R] the frames that ``restarted`` starts anew (dead ends) and the frames no class is possible at."""
    return np.flatnonzero((restarted.link != original.link) | ~np.isfinite(original.unary).any(axis=1))


def decode_filter(factors: ChainFactors) -> Decoded:
    """Decode online, as ``Filter`` does frame by frame, restarting the chain at each dead end as it does."""
    if len(factors.link) == 0:
        return Decoded.empty(factors.n_classes)
    forward = _forward(factors)
    with np.errstate(divide="ignore"):  # exp of the log-probabilities `filtered` gives: the same numbers
        probabilities = np.exp(np.log(forward.alpha))
    return Decoded(probabilities, probabilities.argmax(axis=1), dead_ends(factors, forward.factors))


def decode_viterbi(factors: ChainFactors) -> Decoded:
    """Decode offline: the most probable path, with the forward-backward marginals as probabilities, restarting the
    chain at each dead end as ``Filter`` does."""
    if len(factors.link) == 0:
        return Decoded.empty(factors.n_classes)
    forward = _forward(factors)
    with np.errstate(divide="ignore"):  # exp of the log-probabilities `smoothed` gives: the same numbers
        probabilities, path = np.exp(np.log(_smoothed(forward)[0])), viterbi(forward.factors)
    return Decoded(probabilities, path, dead_ends(factors, forward.factors))


def chain_starts(episode: np.ndarray, split: np.ndarray | None = None, rows: np.ndarray | None = None) -> np.ndarray:
    """bool [T]: where a chain starts in frames listed in episode order: the first frame, and wherever the
    episode (or the split, within an episode) changes from the previous row. ``rows`` (ascending indices, or a bool
    mask): the chains of those rows alone (bool [len(rows)]), a chain also starting where a row does not follow the
    previous one (a gap: rows left out between them)."""
    episode = np.asarray(episode)
    split = None if split is None else np.asarray(split)
    if rows is not None:
        rows = np.asarray(rows)
        rows = np.flatnonzero(rows) if rows.dtype == bool else rows
        episode, split = episode[rows], None if split is None else split[rows]
    starts = np.ones(len(episode), dtype=bool)
    starts[1:] = episode[1:] != episode[:-1]
    if split is not None:
        starts[1:] |= split[1:] != split[:-1]
    if rows is not None:
        starts[1:] |= np.diff(rows) > 1
    return starts


def path_score(factors: ChainFactors, labels: np.ndarray) -> float:
    """The log-potential of one class path: sum_t unary[t, y_t] + sum of the pairwise terms that link frames
    (log p(path) = path_score - log_partition)."""
    labels = np.asarray(labels, dtype=np.int64)
    frames = np.arange(len(labels))
    joined = np.flatnonzero(factors.link >= 0)
    return float(factors.unary[frames, labels].sum()
                 + factors.pairwise[factors.link[joined], labels[joined - 1], labels[joined]].sum())
