"""eval: score the predictions of ``predictions.parquet`` on the test split (metrics: stages/timeline/metrics.py).

The paper's segment metric, per-class and early-recognition accuracy, frame accuracy, macro F1 over
segments, the confusion matrix and, for methods that see no segment boundaries, the edit score and
F1@{10, 25, 50}.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.timeline.metrics import score_method
from mlnseq.catalog import methods


@dataclass(frozen=True)
class EvalOptions:
    """Options of `mlnseq eval`."""

    method: str = "all"  # a method name as predictions name it (``network`` for the network alone), or all
    fraction: float = 0.5

    def validate(self) -> None:
        if self.method != "all":
            methods.parse_method(self.method)
        if not 0 < self.fraction <= 1:
            raise BadInput(f"--fraction must be in (0, 1], got {self.fraction}")

    @property
    def stored_name(self) -> str:
        """The method as predictions.parquet names it (``network+filter`` is ``lstm+filter``), or all."""
        return self.method if self.method == "all" else methods.decoded_name(*methods.parse_method(self.method))


def evaluate(predictions: pl.DataFrame, meta: dict[str, Any], options: EvalOptions) -> dict[str, dict[str, Any]]:
    """Score the chosen methods on the test split of a predictions table."""
    available = meta["methods"]
    chosen = available if options.method == "all" else [options.stored_name]
    for method in chosen:
        if method not in available:
            raise BadInput(f"predictions.parquet has no {method!r} predictions (it has {', '.join(available)}); "
                           f"{_remedy(method)}")
    test = predictions.filter(pl.col("split") == "test")
    if test.height == 0:
        raise BadInput("predictions.parquet has no test frames: rerun `mlnseq collect` with a test split (fit keeps "
                       "none below 5 labelled recordings: their cross-validated figures are the estimate; "
                       "--holdout share keeps one)")
    labels = test["label"].to_numpy().astype(np.int64)
    episodes = test["episode"].to_numpy()
    n_classes = len(meta["classes"])
    results: dict[str, dict[str, Any]] = {}
    scored: dict[tuple[bytes, bool], dict[str, Any]] = {}  # methods predicting alike (decoders often agree): once
    for method in chosen:
        predicted = test[artifacts.pred_column(method)].to_numpy().astype(np.int64)
        key = (predicted.tobytes(), meta["modes"][method] != "segment")
        if key not in scored:
            scored[key] = score_method(predicted, labels, episodes, n_classes, options.fraction, segmental=key[1])
        results[method] = scored[key]
    return results


def _remedy(method: str) -> str:
    base, decode = methods.parse_method(method)
    network = methods.network_of(base)
    stage = "learn-weights" if network is None else f"train --method {network}"
    return f"run `mlnseq {stage}` then `mlnseq conflate" + ("`" if decode == "none" else f" --decode {decode}`")


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
    return pl.DataFrame(rows, schema=artifacts.METRICS_SCHEMA, orient="row")


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
    meta = artifacts.read_metadata(predictions_path, "predictions")
    scored = [m for m in meta["methods"] if options.method == "all" or m == options.stored_name]
    predictions = artifacts.read_rows(predictions_path,  # the classes, not the probabilities
                                      ["split", "label", "episode", *map(artifacts.pred_column, scored)])
    results = evaluate(predictions, meta, options)
    table = metrics_table(results, meta["classes"], options.fraction)
    path = artifacts.write_table(table, Path(workdir) / artifacts.METRICS, "metrics",
                                 {"options": {"method": options.method, "fraction": options.fraction}},
                                 inputs=[predictions_path])
    return EvalResult(path, results, meta["classes"], meta["modes"])
