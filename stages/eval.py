"""eval: score the predictions of ``predictions.parquet`` on the test split.

The paper's metric: each ground-truth test segment (maximal run of one label within an episode) is
recognised from the prediction at its frame ``max(int(len·fraction) − 1, 0)`` (fraction 0.5 in the
paper; the authors' index int(len·fraction) − 1 is −1 for a one-frame segment, taken here as its
frame 0); accuracy over segments, per true class (Table IV), and over fractions 0.1 … 0.9 (the
early-recognition curve). Also frame-wise accuracy, the segment confusion matrix, macro F1 over
segments and, for methods that see no segment boundaries (stream mode and the MLN alone), the
segmental edit score and F1@{10, 25, 50} of Lea et al. / MS-TCN, tp/fp/fn summed over episodes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from stages import artifacts, sequences
from stages.conflate import METHODS, pred_column
from stages.errors import BadInput

EARLY_FRACTIONS = tuple(round(0.1 * i, 1) for i in range(1, 10))
OVERLAPS = (0.10, 0.25, 0.50)


@dataclass(frozen=True)
class EvalOptions:
    """Options of `mlnseq eval`."""

    method: str = "all"
    fraction: float = 0.5

    def validate(self) -> None:
        if self.method not in (*METHODS, "all"):
            raise BadInput(f"unknown --method {self.method!r}: choose one of {', '.join(METHODS)}, all")
        if not 0 < self.fraction <= 1:
            raise BadInput(f"--fraction must be in (0, 1], got {self.fraction}")


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
    p, t = np.array(label_runs(predicted), dtype=np.int64).reshape(-1, 3), np.array(label_runs(truth), dtype=np.int64).reshape(-1, 3)
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


def evaluate(predictions: pl.DataFrame, meta: dict[str, Any], options: EvalOptions) -> dict[str, dict[str, Any]]:
    """Score the chosen methods on the test split of a predictions table."""
    available = meta["methods"]
    chosen = available if options.method == "all" else [options.method]
    for method in chosen:
        if method not in available:
            raise BadInput(f"predictions.parquet has no {method!r} predictions (it has {', '.join(available)}); "
                           f"run `mlnseq {_stage_for(method)}` then `mlnseq conflate`")
    test = predictions.filter(pl.col("split") == "test")
    if test.height == 0:
        raise BadInput("predictions.parquet has no test frames: rerun `mlnseq collect` with a test split")
    labels = test["label"].to_numpy().astype(np.int64)
    episodes = test["episode"].to_numpy()
    n_classes = len(meta["classes"])
    return {
        method: score_method(test[pred_column(method)].to_numpy().astype(np.int64), labels, episodes,
                             n_classes, options.fraction, meta["modes"][method] != "segment")
        for method in chosen
    }


def _stage_for(method: str) -> str:
    return {"lstm": "train --method lstm", "priorlayer": "train --method priorlayer",
            "conflation": "train --method lstm", "combined": "train --method priorlayer",
            "mln": "learn-weights"}[method]


def metrics_table(results: dict[str, dict[str, Any]], classes: list[str], fraction: float) -> pl.DataFrame:
    """Long format: method, metric, item (class name, fraction or ''), value."""
    rows = []
    for method, result in results.items():
        for metric in ("segment_accuracy", "frame_accuracy", "macro_f1", "edit", "f1@10", "f1@25", "f1@50"):
            if metric in result:
                item = str(fraction) if metric == "segment_accuracy" else ""
                rows.append((method, metric, item, result[metric]))
        for k, value in result["per_class"].items():
            rows.append((method, "class_accuracy", classes[k], value))
        for f, value in result["early"].items():
            rows.append((method, "early_accuracy", str(f), value))
        for i, row in enumerate(result["confusion"]):
            for j, count in enumerate(row):
                rows.append((method, "confusion", f"{classes[i]} -> {classes[j]}", float(count)))
    return pl.DataFrame(rows, schema={"method": pl.String, "metric": pl.String, "item": pl.String,
                                      "value": pl.Float64}, orient="row")


@dataclass(frozen=True)
class EvalResult:
    path: Path
    results: dict[str, dict[str, Any]]
    classes: list[str]
    modes: dict[str, str]


def run(workdir: Path, options: EvalOptions) -> EvalResult:
    """Read ``workdir/predictions.parquet``; write ``workdir/metrics.parquet``."""
    options.validate()
    predictions_path = Path(workdir) / artifacts.PREDICTIONS
    predictions, meta = artifacts.read_table(predictions_path, "predictions")
    results = evaluate(predictions, meta, options)
    table = metrics_table(results, meta["classes"], options.fraction)
    path = artifacts.write_table(table, Path(workdir) / artifacts.METRICS, "metrics",
                                 {"options": {"method": options.method, "fraction": options.fraction}},
                                 inputs=[predictions_path])
    return EvalResult(path, results, meta["classes"], meta["modes"])
