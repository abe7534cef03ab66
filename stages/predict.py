"""predict: a model file over new recordings (CSV or Parquet, a file or a folder of them).

The recordings are read as `collect --env table` reads them (the same column options); every frame of
every episode is recognised, and written with its keys, its class name and every class's probability.
When the recordings carry labels, the eval metrics are computed too (each episode scored as a stream:
segment, frame, edit and F1@k).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from stages import artifacts, metrics
from stages.errors import BadInput
from stages.methods import DECODES
from stages.recognizer import Recognizer
from stages.table_import import TableColumns, import_table


@dataclass(frozen=True)
class PredictOptions:
    """Options of `mlnseq predict`."""

    model: Path
    source: Path
    output: Path | None = None  # default: SOURCE's name + .predictions.parquet, in the current folder
    decode: str | None = None  # default: the model's own; viterbi decodes a filter model offline
    columns: TableColumns = field(default_factory=TableColumns)  # label, episode, time (features: the model's)

    def validate(self) -> None:
        if self.decode is not None and self.decode not in DECODES:
            raise BadInput(f"unknown --decode {self.decode!r}: choose one of {', '.join(DECODES)}")
        if self.columns.features:
            raise BadInput("predict reads the model's own features; leave out --features")

    def output_path(self) -> Path:
        return Path(self.output) if self.output is not None else Path(f"{Path(self.source).stem}.predictions.parquet")


def probability_column(name: str) -> str:
    return f"p_{name}"


@dataclass(frozen=True)
class Predicted:
    path: Path
    table: pl.DataFrame
    metrics: dict[str, Any] | None  # with labels in the recordings
    episodes: int


def predict(model: Recognizer, frames: pl.DataFrame, decode: str | None = None) -> tuple[pl.DataFrame, np.ndarray]:
    """Per frame of ``frames`` (keys and the model's features): its keys, class name and probabilities; and
    the predicted class indices."""
    probabilities, predicted = model.predict(frames.select(model.features).to_numpy(), frames["episode"].to_numpy(),
                                             decode)
    keys = frames.select("episode", "frame", *(["label"] if (frames["label"] >= 0).all() else []))
    return keys.with_columns(
        pl.Series("class", np.array(model.classes)[predicted], dtype=pl.String),
        *(pl.Series(probability_column(name), probabilities[:, k], dtype=pl.Float32)
          for k, name in enumerate(model.classes)),
    ), predicted


def run(options: PredictOptions) -> Predicted:
    """Read the model and the recordings; write the per-frame predictions (and metrics, given labels)."""
    options.validate()
    model = Recognizer.load(options.model)
    columns = TableColumns(label=options.columns.label, episode=options.columns.episode, time=options.columns.time,
                           features=tuple(model.features), classes=tuple(model.classes))
    frames, meta = import_table(Path(options.source), columns, for_prediction=True)
    table, predicted = predict(model, frames, options.decode)
    scores = None
    if meta["labelled"]:
        scores = metrics.score_method(predicted, frames["label"].to_numpy().astype(np.int64),
                                      frames["episode"].to_numpy(), len(model.classes), 0.5, segmental=True)
    decode = options.decode or model.decode
    path = artifacts.write_table(
        table, options.output_path(), "predicted",
        {"model": str(Path(options.model).resolve()), "method": model.method, "decode": decode,
         "classes": model.classes, "episodes": meta["episode_names"], "metrics": scores},
        inputs=[Path(options.model), *map(Path, meta["source_files"])],
    )
    return Predicted(path, table, scores, len(meta["episode_names"]))
