"""LeRobot 0.6.1's language annotations, as its annotation pipeline writes them and ``LeRobotDataset`` reads them.

Two columns of every data file, each declared in ``meta/info.json`` as ``{"dtype": "language", "shape": [1],
"names": null}``: ``language_persistent`` holds on every frame of an episode the same list of rows
``{role, content, style, timestamp, camera, tool_calls}`` (a state that holds from its ``timestamp`` until the
next row of its style), ``language_events`` the rows fired at that frame (no timestamp). A frame's subtask is
LeRobot's ``active_at(t, persistent=..., style="subtask")``: the ``subtask`` row with the latest timestamp at or
before the frame's. Keys starting with ``mlnseq.`` are columns mlnseq wrote; neither they nor the language
columns are ever read as features.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa

from mlnseq.catalog.errors import BadInput
from mlnseq.timeline.sequences import run_starts

PERSISTENT, EVENTS = "language_persistent", "language_events"
LANGUAGE = "language"  # the dtype info.json gives both columns
DECLARATION = {"dtype": LANGUAGE, "shape": [1], "names": None}
SUBTASK = "subtask"  # the style of a subtask row (LeRobot's ``${subtask}``)
ROLE = "assistant"  # the role LeRobot's pipeline gives a subtask row
OWN_PREFIX = "mlnseq."  # the keys mlnseq writes into a dataset
PROBABILITIES = "mlnseq.subtask_probabilities"  # predict --write-lerobot-probabilities: one value per class


def _row_fields(timestamp: bool) -> list[pa.Field]:
    fields = [pa.field("role", pa.string()), pa.field("content", pa.string()), pa.field("style", pa.string())]
    return [*fields, *([pa.field("timestamp", pa.float32())] if timestamp else []),
            pa.field("camera", pa.string()), pa.field("tool_calls", pa.list_(pa.string()))]


PERSISTENT_TYPE = pa.list_(pa.struct(_row_fields(timestamp=True)))  # as LeRobot 0.6.1 writes the columns
EVENTS_TYPE = pa.list_(pa.struct(_row_fields(timestamp=False)))


def is_language(name: str, spec: Any) -> bool:
    return name in (PERSISTENT, EVENTS) or (isinstance(spec, dict) and spec.get("dtype") == LANGUAGE)


def written_by_mlnseq(name: str) -> bool:
    return name.startswith(OWN_PREFIX)


def not_a_feature(name: str, spec: Any) -> str | None:
    """Why the info.json feature ``name`` is never read as a feature, or None."""
    if is_language(name, spec):
        return (f"{name} holds LeRobot's language annotations (lists of rows), not values; read its subtasks as "
                "labels with --labels subtask")
    if written_by_mlnseq(name):
        return f"{name} is a column mlnseq wrote (predict --write-lerobot); earlier predictions never become inputs"
    return None


def active(table: pl.DataFrame, time: pl.Series, style: str = SUBTASK, where: str = "") -> tuple[pl.Series, pl.Series]:
    """Per row of ``table`` (with ``episode_index`` and ``language_persistent``): the content of the ``style`` row
    active at its ``time`` (null before the first), and whether its episode has any row of that style."""
    rows = pl.DataFrame({"_row": np.arange(table.height), "_episode": table["episode_index"],
                         "_t": time.cast(pl.Float64), "_rows": table[PERSISTENT]})
    found = _of_style(rows, style).select("_row", "_episode", "_t", "content", "timestamp")
    annotated = rows["_episode"].is_in(found["_episode"].unique().implode())
    latest = (found.filter(pl.col("timestamp").cast(pl.Float64) <= pl.col("_t"))
              .filter(pl.col("timestamp") == pl.col("timestamp").max().over("_row")))
    tied = latest.filter(pl.col("_row").is_duplicated())
    if tied.height:
        first = tied.row(0, named=True)
        raise BadInput(f"{where} episode {first['_episode']}: two {style} rows at {first['timestamp']:g} s "
                       f"({', '.join(map(repr, tied.filter(pl.col('_row') == first['_row'])['content']))}); LeRobot's "
                       "active_at refuses them too: keep one")
    content = rows.select("_row").join(latest.select("_row", "content"), on="_row", how="left")
    return content["content"].alias("label"), annotated


def annotated_episodes(table: pl.DataFrame, style: str = SUBTASK) -> set:
    """The episodes of ``table`` (``episode_index``, ``language_persistent``) with a row of ``style``."""
    rows = table.select(pl.col("episode_index").alias("_episode"), pl.col(PERSISTENT).alias("_rows"))
    return set(_of_style(rows, style)["_episode"].unique().to_list())


def _of_style(rows: pl.DataFrame, style: str) -> pl.DataFrame:
    """The language rows of ``style`` in the lists of column ``_rows``, one a line beside the other columns."""
    return rows.explode("_rows").unnest("_rows").filter(pl.col("style") == style)


def rows_of(classes: list[str], timestamps: np.ndarray) -> list[dict[str, Any]]:
    """One episode's classes frame by frame as subtask rows: one per run, at its first frame's timestamp."""
    labels = np.asarray(classes, dtype=object)
    return [{"role": ROLE, "content": str(labels[k]), "style": SUBTASK, "timestamp": float(timestamps[k]),
             "camera": None, "tool_calls": None} for k in run_starts(labels)]


def merged(own: list[dict[str, Any]] | None, subtasks: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """An episode's rows of other styles kept, its subtask rows replaced, in LeRobot's order (timestamp, style,
    role)."""
    kept = [row for row in own or [] if row.get("style") != SUBTASK]
    return sorted([*kept, *subtasks], key=lambda row: (float(row["timestamp"]), row.get("style") or "",
                                                        row.get("role") or ""))
