"""The recognition metrics, on arrays of predicted and true class indices.

The paper's metric: each ground-truth segment (maximal run of one label within an episode) is
recognised from the prediction at its frame ``max(int(len·fraction) − 1, 0)`` (fraction 0.5 in the
paper; the authors' index int(len·fraction) − 1 is −1 for a one-frame segment, taken here as its
frame 0); accuracy over segments, per true class (Table IV), and over fractions 0.1 … 0.9 (the
early-recognition curve). Also frame-wise accuracy, the segment confusion matrix, macro F1 over
segments (each class's F1 from that confusion matrix, averaged over the classes that occur) and, for
methods that see no segment boundaries (stream mode, the MLN alone, decoding), the segmental edit
score and F1@{10, 25, 50} of Lea et al. / MS-TCN, tp/fp/fn summed over episodes.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from mlnseq.timeline import sequences

EARLY_FRACTIONS = tuple(round(0.1 * i, 1) for i in range(1, 10))
OVERLAPS = (0.10, 0.25, 0.50)


def segment_frame(length: int | np.ndarray, fraction: float) -> int | np.ndarray:
    """The frame of a segment (or of each of an array of segments) whose prediction recognises it:
    max(int(length·fraction) − 1, 0)."""
    return np.maximum((np.asarray(length) * fraction).astype(np.int64) - 1, 0)


def segment_predictions(starts: np.ndarray, lengths: np.ndarray, predictions: np.ndarray,
                        fraction: float) -> np.ndarray:
    """The prediction recognising each segment (``starts``, ``lengths``): :func:`segment_frame` of every one at once."""
    return predictions[starts + segment_frame(lengths, fraction)]


def label_runs(labels: np.ndarray) -> list[tuple[int, int, int]]:
    """(label, start, stop) of each maximal run of one label."""
    return [(int(labels[s.start]), s.start, s.stop) for s in sequences.runs(np.asarray(labels))]


def levenshtein(a: np.ndarray | Sequence[int], b: np.ndarray | Sequence[int]) -> int:
    """Levenshtein distance of two integer sequences, bit-parallel (Myers 1999, Hyyrö's global form): a column of
    the distance table is a bit vector over ``a`` as one Python integer, so a step of ``b`` is a dozen word-wide
    operations over len(a) / 64 words instead of len(a) cells. Exact; still len(a) x len(b) / 64 work."""
    m = len(a)
    if not m or not len(b):
        return max(m, len(b))
    a, b = (x.tolist() if isinstance(x, np.ndarray) else x for x in (a, b))
    positions: dict[int, int] = {}  # per symbol, the bits of the rows of a that hold it
    for i, symbol in enumerate(a):
        positions[symbol] = positions.get(symbol, 0) | (1 << i)
    mask, top = (1 << m) - 1, 1 << (m - 1)
    plus, minus, distance = mask, 0, m  # vertical deltas +1 / -1 of the current column; D[m][j]
    for symbol in b:
        equal = positions.get(symbol, 0)
        x_vertical = equal | minus
        x_horizontal = ((((equal & plus) + plus) & mask) ^ plus) | equal
        h_plus = minus | (mask & ~(x_horizontal | plus))
        h_minus = plus & x_horizontal
        distance += 1 if h_plus & top else -1 if h_minus & top else 0
        h_plus = ((h_plus << 1) | 1) & mask  # row 0 of the table is 0, 1, 2, ...: a +1 enters at the top
        h_minus = (h_minus << 1) & mask
        plus = h_minus | (mask & ~(x_vertical | h_plus))
        minus = h_plus & x_vertical
    return distance


def edit_score(predicted: np.ndarray, truth: np.ndarray) -> float:
    """100·(1 − Levenshtein distance of the segment label sequences / the longer one's length)."""
    return _edit(_runs_array(predicted)[:, 0], _runs_array(truth)[:, 0])


def _edit(p: np.ndarray | Sequence[int], t: np.ndarray | Sequence[int]) -> float:
    if not len(p) and not len(t):
        return 100.0
    return float(100 * (1 - levenshtein(p, t) / max(len(p), len(t))))


def edit_scores(predicted: np.ndarray, truth: np.ndarray, episodes: np.ndarray) -> list[float]:
    """:func:`edit_score` of each episode (a maximal run of ``episodes``), the runs of all found at once; episodes
    with the same two label sequences (most, over many short episodes) are scored once."""
    p, t = _runs_array(predicted, episodes), _runs_array(truth, episodes)
    if not len(p):
        return []
    first = sequences.run_starts(episodes)
    scored: dict[tuple[tuple[int, ...], tuple[int, ...]], float] = {}
    out = []
    for pair in zip(_by_episode(p, first), _by_episode(t, first)):
        if pair not in scored:
            scored[pair] = _edit(*pair)
        out.append(scored[pair])
    return out


def _by_episode(runs: np.ndarray, first: np.ndarray) -> list[tuple[int, ...]]:
    """The labels of ``runs`` (cut at every episode start ``first``) split per episode."""
    labels = runs[:, 0].tolist()
    cuts = [0, *np.searchsorted(runs[:, 1], first[1:]).tolist(), len(labels)]
    return [tuple(labels[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]


def _runs_array(labels: np.ndarray, episodes: np.ndarray | None = None) -> np.ndarray:
    """[label, start, stop] int64 rows of the maximal runs of one label (label_runs as an array), also cut where
    ``episodes`` changes."""
    labels = np.asarray(labels)
    if not len(labels):
        return np.zeros((0, 3), dtype=np.int64)
    starts = sequences.run_starts(labels, *([] if episodes is None else [episodes]))
    stops = np.r_[starts[1:], len(labels)]
    return np.stack([labels[starts].astype(np.int64), starts, stops], axis=1).astype(np.int64)


def best_matches(p: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per predicted segment (rows [label, start, stop] of ``p``), the true segment of ``t`` (sorted in time, not
    overlapping) with the highest IoU, -1 where the classes differ, and that IoU; the first maximum, as argmax over
    every true segment takes it. Only the true segments a predicted one overlaps can have a positive IoU, and those
    are a contiguous range found by binary search: O((P + T) log T) and the overlapping pairs, P + T at most when
    both cover the same frames."""
    n_p = len(p)
    lo = np.searchsorted(t[:, 2], p[:, 1], side="right")  # the first true segment ending after p starts
    hi = np.searchsorted(t[:, 1], p[:, 2], side="left")  # the first true segment starting at or after p's end
    count = np.maximum(hi - lo, 0)
    owner = np.repeat(np.arange(n_p), count)
    first = np.cumsum(count) - count
    pair_t = lo[owner] + np.arange(len(owner)) - first[owner]
    ps, ts = p[owner], t[pair_t]
    intersection = np.minimum(ps[:, 2], ts[:, 2]) - np.maximum(ps[:, 1], ts[:, 1])
    union = np.maximum(ps[:, 2], ts[:, 2]) - np.minimum(ps[:, 1], ts[:, 1])
    iou = np.where(ps[:, 0] == ts[:, 0], np.maximum(intersection, 0) / union, -1.0)
    # without an overlapping true segment of its class: 0 at the first true segment of its class, else -1 at 0
    classes, first_of_class = np.unique(t[:, 0], return_index=True)
    place = np.minimum(np.searchsorted(classes, p[:, 0]), len(classes) - 1)
    same = classes[place] == p[:, 0]
    best = np.where(same, first_of_class[place], 0)
    best_iou = np.where(same, 0.0, -1.0)
    positive = iou > 0
    if positive.any():
        owners, pairs = owner[positive], np.flatnonzero(positive)
        top = np.full(n_p, -np.inf)
        np.maximum.at(top, owners, iou[positive])
        at_top = iou[pairs] == top[owners]
        chosen = np.full(n_p, len(owner))
        np.minimum.at(chosen, owners[at_top], pairs[at_top])  # the first pair (in time) at the maximum
        has = chosen < len(owner)
        best[has], best_iou[has] = pair_t[chosen[has]], iou[chosen[has]]
    return best, best_iou


def overlap_counts_all(predicted: np.ndarray, truth: np.ndarray, overlaps: tuple[float, ...] = OVERLAPS,
                       episodes: np.ndarray | None = None) -> dict[float, tuple[int, int, int]]:
    """tp, fp, fn of segmental F1 at each of ``overlaps``: a predicted segment is a hit when its IoU with a not yet
    matched true segment of the same class reaches the overlap (MS-TCN's f_score). Each predicted segment's best true
    segment is found once for every overlap (:func:`best_matches`). With ``episodes``, the sums over its blocks
    (segments cut where it changes) in one pass: a hit needs a positive IoU, so only overlaps above 0."""
    if episodes is not None and min(overlaps) <= 0:
        raise ValueError(f"overlaps over several episodes must be positive, got {min(overlaps)}")
    p, t = _runs_array(predicted, episodes), _runs_array(truth, episodes)
    if not len(t):
        return {o: (0, len(p), 0) for o in overlaps}
    best, best_iou = best_matches(p, t)
    counts = {}
    for o in overlaps:
        # in time order a hit on an unmatched true segment counts, later hits on it are false positives
        tp = len(np.unique(best[best_iou >= o]))
        counts[o] = (tp, len(p) - tp, len(t) - tp)
    return counts


def overlap_counts(predicted: np.ndarray, truth: np.ndarray, overlap: float) -> tuple[int, int, int]:
    """tp, fp, fn of segmental F1@overlap (:func:`overlap_counts_all` at one overlap)."""
    return overlap_counts_all(predicted, truth, (overlap,))[overlap]


def f1(tp: int, fp: int, fn: int) -> float:
    precision = tp / (tp + fp) if tp + fp else 0.0
    recall = tp / (tp + fn) if tp + fn else 0.0
    return float(100 * 2 * precision * recall / (precision + recall)) if precision + recall else 0.0


def score_method(
    predictions: np.ndarray, labels: np.ndarray, episodes: np.ndarray, n_classes: int, fraction: float,
    segmental: bool,
) -> dict[str, Any]:
    """Every metric of one method on test frames (rows in order; ``episodes`` delimits sequences)."""
    spans = _runs_array(labels, episodes)  # the true segments
    starts, lengths, truth = spans[:, 1], spans[:, 2] - spans[:, 1], spans[:, 0]
    recognised = segment_predictions(starts, lengths, predictions, fraction)
    confusion = np.zeros((n_classes, n_classes), dtype=np.int64)
    np.add.at(confusion, (truth, recognised), 1)
    per_class = {k: float(confusion[k, k] / confusion[k].sum()) if confusion[k].sum() else float("nan")
                 for k in range(n_classes)}
    f1_per_class = []
    for k in range(n_classes):
        tp, fp, fn = confusion[k, k], confusion[:, k].sum() - confusion[k, k], confusion[k].sum() - confusion[k, k]
        if tp + fp + fn:
            f1_per_class.append(f1(int(tp), int(fp), int(fn)) / 100)
    result: dict[str, Any] = {
        "segment_accuracy": float((recognised == truth).mean()),
        "frame_accuracy": float((predictions == labels).mean()),
        "per_class": per_class,
        "early": {f: float((segment_predictions(starts, lengths, predictions, f) == truth).mean())
                  for f in EARLY_FRACTIONS},
        "macro_f1": float(np.mean(f1_per_class)),
        "confusion": confusion.tolist(),
        "n_segments": len(spans),
    }
    if segmental:
        result["edit"] = float(np.mean(edit_scores(predictions, labels, episodes)))
        counts = overlap_counts_all(predictions, labels, OVERLAPS, episodes)  # tp, fp, fn summed over episodes
        for o in OVERLAPS:
            result[f"f1@{int(o * 100)}"] = f1(*counts[o])
    return result
