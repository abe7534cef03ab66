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
from stages.recognizer import METHODS
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
    p = [r[0] for r in label_runs(predicted)]
    t = [r[0] for r in label_runs(truth)]
    if not p and not t:
        return 100.0
    d = np.zeros((len(p) + 1, len(t) + 1))
    d[:, 0] = np.arange(len(p) + 1)
    d[0, :] = np.arange(len(t) + 1)
    for i in range(1, len(p) + 1):
        for j in range(1, len(t) + 1):
            d[i, j] = min(d[i - 1, j] + 1, d[i, j - 1] + 1, d[i - 1, j - 1] + (p[i - 1] != t[j - 1]))
    return float(100 * (1 - d[-1, -1] / max(len(p), len(t))))


def overlap_counts(predicted: np.ndarray, truth: np.ndarray, overlap: float) -> tuple[int, int, int]:
    """tp, fp, fn of segmental F1@overlap: a predicted segment is a hit when its IoU with a not yet
    matched true segment of the same class reaches ``overlap`` (MS-TCN's f_score)."""
    p, t = label_runs(predicted), label_runs(truth)
    matched = np.zeros(len(t), dtype=bool)
    tp = fp = 0
    for label, start, stop in p:
        best, best_iou = -1, -1.0
        for j, (t_label, t_start, t_stop) in enumerate(t):
            if t_label != label:
                continue
            intersection = min(stop, t_stop) - max(start, t_start)
            union = max(stop, t_stop) - min(start, t_start)
            iou = max(intersection, 0) / union
            if iou > best_iou:
                best, best_iou = j, iou
        if best >= 0 and best_iou >= overlap and not matched[best]:
            tp += 1
            matched[best] = True
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
        method: score_method(test[artifacts.pred_column(method)].to_numpy().astype(np.int64), labels, episodes,
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
