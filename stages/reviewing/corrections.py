"""The labels a review saves: one intervals CSV (``episode,start,end,label``, stages/sources/intervals.py: what
`collect --labels` and `fit --labels` read as it is), in the unit the recordings' source reads labels in. A save
writes the file whole (a temporary file renamed over it); the recordings saved before, by this review or an earlier
one, keep their rows. Its path is fixed when the review starts: nothing the browser sends names a file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.sources import intervals


def check_path(save: Path, source: Path, inputs: list[Path]) -> None:
    """Refuse a labels file inside the source (a save never writes into the recordings), or one of the inputs."""
    target = Path(save).resolve()
    root = Path(source).resolve()
    if target == root or (root.is_dir() and target.is_relative_to(root)):
        raise BadInput(f"--save {save} is inside the source {source}: a review never writes into the recordings; "
                       "name a file outside it")
    for path in inputs:
        if target == Path(path).resolve():
            raise BadInput(f"--save {save} is {path}, an input of this review; name another file")
    if target.is_dir():
        raise BadInput(f"--save {save} is a folder; name a CSV file")


def labels_of(segments: Any, frames: int, classes: list[str]) -> list[str]:
    """Each frame's class name from a save's segments: [first, last, class name] in order, covering every frame."""
    if not isinstance(segments, list) or not segments:
        raise BadInput("a save needs segments: [[first frame, last frame, class], ...]")
    names: list[str] = []
    for k, segment in enumerate(segments):
        if (not isinstance(segment, list) or len(segment) != 3 or not all(type(v) is int for v in segment[:2])
                or segment[2] not in classes):
            raise BadInput(f"segment {k}: expected [first frame, last frame, one of {', '.join(classes)}]")
        first, last, name = segment
        if first != len(names) or last < first or last >= frames:
            raise BadInput(f"segment {k}: frames {first}-{last} do not follow on from frame {len(names)} "
                           f"(the recording has {frames} frames)")
        names += [name] * (last - first + 1)
    if len(names) != frames:
        raise BadInput(f"the segments cover {len(names)} of the recording's {frames} frames")
    return names


class LabelsFile:
    """The labels file of a review: its rows by episode, those read at the start kept until the episode is saved."""

    def __init__(self, path: Path, unit: str):
        self.path, self.unit = Path(path), unit
        self.rows: dict[str, pl.DataFrame] = {}
        self.read: dict[str, list[intervals.Interval]] = {}
        if self.path.is_file():
            self.read = intervals.read(self.path)
            table = pl.read_csv(self.path, schema_overrides={"episode": pl.String}).select(intervals.COLUMNS)
            for episode in self.read:
                self.rows[episode] = table.filter(pl.col("episode") == episode)

    def saved(self, episode: str, time: np.ndarray, classes: list[str]) -> np.ndarray | None:
        """The episode's labels in the file, as class indices per frame (-1: outside every interval)."""
        found = self.read.get(episode)
        if found is None:
            return None
        key = np.arange(len(time), dtype=np.float64) if self.unit == "frames" else np.asarray(time, dtype=float)
        labels = np.full(len(time), -1, dtype=np.int64)
        for interval in found:
            if str(interval.label) not in classes:
                raise BadInput(f"{interval.where}: label {interval.label!r} is not a class of the model "
                               f"({', '.join(classes)})")
            before_end = (key <= interval.end) if self.unit == "frames" else (key < interval.end)
            inside = (key >= interval.start) & before_end
            labels[inside] = classes.index(str(interval.label))
        return labels

    def put(self, episode: str, time: np.ndarray, names: list[str]) -> int:
        """The episode's labels (a class name per frame) as its rows; returns how many."""
        rows = intervals.segments([episode] * len(names), np.arange(len(names)), np.asarray(time, dtype=float),
                                  names, self.unit)
        self.rows[episode] = rows.with_columns(pl.col(pl.Float64).round(9)) if self.unit != "frames" else rows
        self.read[episode] = [intervals.Interval(s, e, label, f"{self.path}") for s, e, label in
                              rows.select("start", "end", "label").iter_rows()]
        return rows.height

    def write(self) -> Path:
        """The whole file, every episode's rows in the order they were first saved, or nothing."""
        tables = [table.with_columns(pl.col("start", "end").cast(pl.Float64 if self.unit != "frames" else pl.Int64))
                  for table in self.rows.values()]
        with artifacts.atomic_path(self.path) as tmp:
            pl.concat(tables).write_csv(tmp, float_scientific=False)
        return self.path
