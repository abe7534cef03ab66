"""The row-wise steps of the lagged decoders (stages/mln/lag.py over whole recordings, stages/mln/lag_online.py
one frame at a time), the same on one row and on many, so that both decoders give the same numbers: the forward
steps, the backward steps (row-major, and class-major for many frames under one transition matrix), the decision
scores and the legal choice of one frame."""

from __future__ import annotations

import numpy as np

from mlnseq.mln.chain_factors import CLIP

MANY = 64  # rows from which a backward step moves its frames by transition matrix and goes class by class
_IN_ORDER = 7  # terms up to which numpy's sum along an axis adds them one after another, first to last


def scaled(values: np.ndarray, axes: tuple[int, ...] = (-1,)) -> np.ndarray:
    """exp(values - max over ``axes``) (each row, or each matrix), finite entries clipped at e^-CLIP, -inf as 0."""
    top = values.max(axis=axes, keepdims=True)
    finite = np.isfinite(values)
    if finite.all():  # the same numbers as below, without its masks (a live step's row is most often all finite)
        return np.exp(np.maximum(values - top, -CLIP))
    with np.errstate(invalid="ignore"):
        shifted = np.where(finite, values - np.where(np.isfinite(top), top, 0.0), 0.0)
    return np.where(finite, np.exp(np.maximum(shifted, -CLIP)), 0.0)


def _normal(values: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows over their totals; a row of total 0 is ``fallback``'s row normalised (all 0: uniform); and which rows."""
    total = values.sum(axis=1)
    dead = ~(total > 0)
    if dead.any():
        rescue = np.where(fallback[dead].sum(axis=1, keepdims=True) > 0, fallback[dead], 1.0)
        values, total = values.copy(), total.copy()
        values[dead], total[dead] = rescue, rescue.sum(axis=1)
    return values / total[:, None], dead


def sum_forward(previous: np.ndarray | None, transition: np.ndarray,
                 linear: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """alpha rows after one step [B, C] and the rows that were dead ends (restarted from the unary alone)."""
    if previous is None:
        alpha, _ = _normal(linear, linear)
        return alpha, np.zeros(len(linear), dtype=bool)
    return _normal((previous[:, :, None] * transition).sum(axis=1) * linear, linear)


def _top(values: np.ndarray) -> np.ndarray:
    top = values.max(axis=1, keepdims=True)
    return np.where(np.isfinite(top), top, 0.0)


def max_forward(previous: np.ndarray | None, log_transition: np.ndarray,
                 unary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """delta rows after one step [B, C] (max 0) and the rows that were dead ends (restarted from the unary alone)."""
    if previous is None:
        return _restart(unary), np.zeros(len(unary), dtype=bool)
    best = (previous[:, :, None] + log_transition).max(axis=1) + unary
    top = best.max(axis=1, keepdims=True)
    dead = ~np.isfinite(top[:, 0])
    if dead.any():
        return np.where(dead[:, None], _restart(unary), best - np.where(dead[:, None], 0.0, top)), dead
    return best - top, dead


def _restart(unary: np.ndarray) -> np.ndarray:
    """delta rows of chains starting at ``unary``: each row less its max (a row with no finite entry: 0)."""
    return np.where(np.isfinite(unary.max(axis=1, keepdims=True)), unary - _top(unary), 0.0)


def _row_max(values: np.ndarray) -> np.ndarray:
    """[N, 1] each row's max, one column at a time where rows are many (numpy's max along a short last axis is slow
    on many rows; a max is exact in any order)."""
    if len(values) < MANY:
        return values.max(axis=1, keepdims=True)
    top = values[:, :1].copy()
    for j in range(1, values.shape[1]):
        np.maximum(top, values[:, j:j + 1], out=top)
    return top


def _over_top(moved: np.ndarray, top: np.ndarray) -> np.ndarray:
    """A backward step's vectors over their top (a row's, or a class-major column's): 1 where the top is 0."""
    positive = top > 0
    if positive.all():  # the same numbers as below, without its masks (the top is 0 only past a dead end)
        return moved / top
    return np.where(positive, moved / np.where(positive, top, 1.0), 1.0)


def _less_top(moved: np.ndarray, top: np.ndarray) -> np.ndarray:
    """A max backward step's vectors less their top: 0 where the top is not finite."""
    finite = np.isfinite(top)
    return np.where(finite, moved - np.where(finite, top, 0.0), 0.0)


def sum_back(vectors: np.ndarray, transition: np.ndarray, linear: np.ndarray) -> np.ndarray:
    moved = (transition * (linear * vectors)[:, None, :]).sum(axis=2)
    return _over_top(moved, _row_max(moved))


def max_back(vectors: np.ndarray, log_transition: np.ndarray, unary: np.ndarray) -> np.ndarray:
    shifted = unary + vectors
    moved = log_transition[:, :, 0] + shifted[:, 0, None]  # the max over the next class, one class at a time
    for j in range(1, shifted.shape[1]):
        np.maximum(moved, log_transition[:, :, j] + shifted[:, j, None], out=moved)
    return _less_top(moved, _row_max(moved))


# The same steps on class-major rows ([C, N]: each class's entries side by side) with one transition matrix [C, C],
# every operation over a contiguous row: a window step moves many frames by the same few matrices.


def rows_of(*by_class: np.ndarray) -> list[np.ndarray]:
    """Class-major arrays as the row-major (C-contiguous) rows the row-wise steps take."""
    return [np.ascontiguousarray(values.T) for values in by_class]


def _class_max(values: np.ndarray) -> np.ndarray:
    top = values[0].copy()
    for row in values[1:]:
        np.maximum(top, row, out=top)
    return top


def sum_back_by_class(vectors: np.ndarray, transition: np.ndarray, linear: np.ndarray) -> np.ndarray:
    if len(vectors) > _IN_ORDER:  # numpy's own order of a row's sum, which depends on the rows' layout
        moving, frame_values = rows_of(vectors, linear)
        return sum_back(moving, transition[None], frame_values).T
    weighted = linear * vectors
    moved = transition[:, :1] * weighted[0]
    for k in range(1, len(weighted)):
        moved += transition[:, k:k + 1] * weighted[k]
    return _over_top(moved, _class_max(moved))


def max_back_by_class(vectors: np.ndarray, log_transition: np.ndarray, unary: np.ndarray) -> np.ndarray:
    shifted = unary + vectors
    moved = log_transition[:, :1] + shifted[0]
    for j in range(1, len(shifted)):
        np.maximum(moved, log_transition[:, j:j + 1] + shifted[j], out=moved)
    return _less_top(moved, _class_max(moved))


def decision_scores(semiring: str, forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """Each frame's decision scores: the normalised marginal (sum) or the max-marginal minus its max (max)."""
    if semiring == "max":
        joint = forward + backward
        return joint - _top(joint)
    joint = forward * backward
    total = joint.sum(axis=1, keepdims=True)
    return np.where(total > 0, joint / np.where(total > 0, total, 1.0), forward)


def legal_label(scores: list[float], allowed_after: list[bool], semiring: str, free: int) -> int:
    """One frame's argmax among the classes allowed after the previous choice (``allowed_after``) that are possible
    given the frames; none possible: the first allowed class; none allowed: ``free``. In plain Python: a legal pass
    decides frame by frame, and a handful of classes costs less than a numpy call."""
    best, top = -1, 0.0 if semiring == "sum" else -np.inf
    for label, (ok, value) in enumerate(zip(allowed_after, scores)):
        if ok and value > top:  # strictly greater: the first of equals, as argmax
            best, top = label, value
    if best >= 0:
        return best
    return allowed_after.index(True) if True in allowed_after else free


def probabilities_of(scores: np.ndarray, semiring: str) -> np.ndarray:
    """Class probabilities [T, C] from decision scores: the marginals, or max-marginals normalised."""
    if semiring == "sum":
        return scores
    weights = np.exp(scores)
    return weights / weights.sum(axis=1, keepdims=True)
