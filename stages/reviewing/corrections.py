"""The labels a review saves: one intervals CSV (``episode,start,end,label,unit``, stages/sources/intervals.py: what
`collect --labels` and `fit --labels` read as it is, each row saying its unit), in the unit the recordings' source
reads labels in. A save writes the file whole (a temporary file renamed over it); the recordings saved before, by
this review or an earlier one, keep their rows, and a fit's own labels file is carried into it (`review -w`). Its
path is fixed when the review starts: nothing the browser sends names a file."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

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
    """The labels file of a review: its rows by episode (intervals, or a fit's clicks carried over), those read at the
    start kept until the episode is saved. Each row says its unit (the file's ``unit`` column), so that `collect
    --labels` and `fit --labels` read it without --labels-unit."""

    def __init__(self, path: Path, unit: str, carried: dict[str, list[intervals.Interval]] | None = None):
        """``unit``: the unit a save writes and a row without its own is read in; ``carried``: the rows of the
        labels file a fit was given (where this file does not exist yet), written with the saves so that the file
        fits again with every label fit had."""
        self.path, self.unit = Path(path), unit
        self.read: dict[str, list[intervals.Interval]] = {}  # this file's own rows, then the saves
        self.carried: dict[str, list[intervals.Interval]] = {}
        if self.path.is_file():
            self.read = {episode: [_with_unit(i, unit) for i in found]
                         for episode, found in intervals.read(self.path).items()}
        elif carried:
            self.carried = {episode: [_with_unit(i, unit) for i in found] for episode, found in carried.items()}
        self.saved_here: set[str] = set()

    @property
    def episodes(self) -> set[str]:
        """The episodes labelled on every frame in this file: saved by this review or an earlier one."""
        return {episode for episode, found in self.read.items() if not found[0].click}

    def saved(self, episode: str, time: np.ndarray, classes: list[str]) -> np.ndarray | None:
        """The episode's labels in the file, as class indices per frame (-1: outside every interval); None where the
        file has none for it, or only clicks."""
        found = self.read.get(episode)
        if not found or found[0].click:
            return None
        labels = np.full(len(time), -1, dtype=np.int64)
        for interval in found:
            if str(interval.label) not in classes:
                raise BadInput(f"{interval.where}: label {interval.label!r} is not a class of the model "
                               f"({', '.join(classes)})")
            key = np.arange(len(time), dtype=np.float64) if interval.unit == "frames" else np.asarray(time, dtype=float)
            labels[interval.covers(key, interval.unit)] = classes.index(str(interval.label))
        return labels

    def put(self, episode: str, time: np.ndarray, names: list[str]) -> int:
        """The episode's labels (a class name per frame) as its rows; returns how many."""
        rows = intervals.segments([episode] * len(names), np.arange(len(names)), np.asarray(time, dtype=float),
                                  names, self.unit)
        self.read[episode] = [intervals.Interval(start, end, label, f"{self.path}", self.unit)
                              for start, end, label in rows.select("start", "end", "label").iter_rows()]
        self.carried.pop(episode, None)
        self.saved_here.add(episode)
        return rows.height

    def write(self) -> Path:
        """The whole file, every episode's rows (those carried from a fit's labels file first), or nothing; one it
        cannot write is refused naming --save."""
        every = {**self.carried, **self.read}
        clicks = any(found[0].click for found in every.values())
        header = ["episode", "start", "end", *(["frame"] if clicks else []), "label", intervals.UNIT_COLUMN]
        lines = [header]
        for episode, found in every.items():
            for i in found:
                at = ["", "", _number(i.start, i.unit)] if i.click else [_number(i.start, i.unit),
                                                                         _number(i.end, i.unit), *([""] * clicks)]
                lines.append([episode, *at, str(i.label), i.unit])
        try:
            with artifacts.atomic_path(self.path) as tmp:
                with tmp.open("w", encoding="utf-8", newline="") as handle:
                    csv.writer(handle, lineterminator="\n").writerows(lines)
        except BadInput as error:  # the folder cannot be written (any more)
            reason = getattr(error.__cause__, "strerror", None) or str(error)
            raise BadInput(f"--save {self.path}: not saved ({reason}); start review again with --save naming a file "
                           "in a folder you can write") from None
        return self.path


def _with_unit(interval: intervals.Interval, unit: str) -> intervals.Interval:
    """An interval read from a file without a unit column, in the unit such a file is read in."""
    return interval if interval.unit is not None else dataclasses.replace(interval, unit=unit)


def _number(value: float, unit: str | None) -> str:
    """A start or end as the file writes it: a frame as a whole number, seconds to the nanosecond."""
    if unit == "frames":
        return str(int(value))
    return f"{float(value):.9f}".rstrip("0").rstrip(".")
