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

from typing import Any

import numpy as np

from mlnseq.timeline import sequences

EARLY_FRACTIONS = tuple(round(0.1 * i, 1) for i in range(1, 10))
OVERLAPS = (0.10, 0.25, 0.50)


def segment_frame(length: int, fraction: float) -> int:
    """The frame of a segment whose prediction recognises it: max(int(length·fraction) − 1, 0)."""
    return max(int(length * fraction) - 1, 0)


def segment_predictions(spans: list[slice], predictions: np.ndarray, fraction: float) -> np.ndarray:
    return np.array([predictions[s.start + segment_frame(s.stop - s.start, fraction)] for s in spans])


def label_runs(labels: np.ndarray) -> list[tuple[int, int, int]]:
    """(label, start, stop) of each maximal run of one label."""
    return [(int(labels[s.start]), s.start, s.stop) for s in sequences.runs(np.asarray(labels))]


def edit_score(predicted: np.ndarray, truth: np.ndarray) -> float:
    """100·(1 − Levenshtein distance of the segment label sequences / the longer one's length)."""
    p = np.array([r[0] for r in label_runs(predicted)], dtype=np.int64)
    t = np.array([r[0] for r in label_runs(truth)], dtype=np.int64)
    if not len(p) and not len(t):
        return 100.0
    columns = np.arange(len(t) + 1)
    row = columns.copy()  # distances from the empty prefix of p
    for i in range(1, len(p) + 1):
        # deletion or substitution from the previous row, then insertions along this row: d[j] = min over k <= j
        # of (best[k] + j - k), a running minimum
        best = np.empty_like(row)
        best[0] = i
        best[1:] = np.minimum(row[1:] + 1, row[:-1] + (t != p[i - 1]))
        row = np.minimum.accumulate(best - columns) + columns
    return float(100 * (1 - row[-1] / max(len(p), len(t))))


def overlap_counts(predicted: np.ndarray, truth: np.ndarray, overlap: float) -> tuple[int, int, int]:
    """tp, fp, fn of segmental F1@overlap: a predicted segment is a hit when its IoU with a not yet
    matched true segment of the same class reaches ``overlap`` (MS-TCN's f_score)."""
    p = np.array(label_runs(predicted), dtype=np.int64).reshape(-1, 3)
    t = np.array(label_runs(truth), dtype=np.int64).reshape(-1, 3)
    matched = np.zeros(len(t), dtype=bool)
    if not len(t):
        return 0, len(p), 0
    # every predicted segment against every true one: IoU, -1 where the classes differ; the best is the first maximum
    intersection = np.minimum(p[:, None, 2], t[None, :, 2]) - np.maximum(p[:, None, 1], t[None, :, 1])
    union = np.maximum(p[:, None, 2], t[None, :, 2]) - np.minimum(p[:, None, 1], t[None, :, 1])
    iou = np.where(p[:, None, 0] == t[None, :, 0], np.maximum(intersection, 0) / union, -1.0)
    best = iou.argmax(axis=1)
    best_iou = iou[np.arange(len(p)), best]
    tp = fp = 0
    for j, hit in zip(best.tolist(), (best_iou >= overlap).tolist()):
        if hit and not matched[j]:
            tp += 1
            matched[j] = True
        else:
            fp += 1
    return tp, fp, int((~matched).sum())


def f1(tp: int, fp: int, fn: int) -> float:
    precision = tp / (tp + fp) if tp + fp else 0.0
    recall = tp / (tp + fn) if tp + fn else 0.0
    return float(100 * 2 * precision * recall / (precision + recall)) if precision + recall else 0.0


def score_method(
    predictions: np.ndarray, labels: np.ndarray, episodes: np.ndarray, n_classes: int, fraction: float,
    segmental: bool,
) -> dict[str, Any]:
    """Every metric of one method on test frames (rows in order; ``episodes`` delimits sequences)."""
    spans = sequences.segments(episodes, np.zeros_like(episodes), labels)
    truth = np.array([labels[s.start] for s in spans])
    recognised = segment_predictions(spans, predictions, fraction)
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
        "early": {f: float((segment_predictions(spans, predictions, f) == truth).mean()) for f in EARLY_FRACTIONS},
        "macro_f1": float(np.mean(f1_per_class)),
        "confusion": confusion.tolist(),
        "n_segments": len(spans),
    }
    if segmental:
        edits, counts = [], {o: np.zeros(3, dtype=np.int64) for o in OVERLAPS}
        for block in sequences.runs(episodes):
            edits.append(edit_score(predictions[block], labels[block]))
            for o in OVERLAPS:
                counts[o] += overlap_counts(predictions[block], labels[block], o)
        result["edit"] = float(np.mean(edits))
        for o in OVERLAPS:
            result[f"f1@{int(o * 100)}"] = f1(*map(int, counts[o]))
    return result
