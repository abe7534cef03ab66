"""What every recording reader makes: ``Recording``s of one file each, read with ``TableColumns``, and whether
the recordings' own labels are read (``Labels``)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl


class Labels(Enum):
    """Whether a reader reads the recordings' own labels."""

    REQUIRED = "required"  # every recording is labelled (predict given --label-column)
    SOME = "some"  # collect: recordings carry labels where they have them, the others are read unlabelled
    OPTIONAL = "optional"  # predict: read where the recordings carry them, the others unlabelled
    NONE = "none"  # not read: ``--labels`` intervals give them, or there are none


@dataclass(frozen=True)
class TableColumns:
    """Which columns of the user's table are keys and which are features."""

    label: str = "label"
    episode: str | None = None  # default: a column named "episode" if present, else one episode per file
    time: str | None = None  # default: a column named "frame" if present, else file order
    features: tuple[str, ...] = ()  # default: every other numeric column
    classes: tuple[str, ...] = ()  # class names in label order; default: from the labels


@dataclass(frozen=True)
class Recording:
    """One file's frames as a source read them; rows are named in messages as ``where`` formats them."""

    path: Path
    features: pl.DataFrame  # one column per feature, in order, numeric and finite
    episode: pl.Series  # the user's episode id per row (Int64 or String)
    time: pl.Series  # rising within an episode
    label: pl.Series | None = None  # class index or name per row; None: unlabelled
    split: pl.Series | None = None  # train/test per row, if the source says
    row: pl.Series | None = None  # the row number messages give (default: 0, 1, ...)
    where: str = "{file} row {row}"  # "{file}:{row}" for a CSV's lines
    resolved: dict[str, Any] = field(default_factory=dict)  # options the source chose (a bag's rate, topics)


def stamps(recordings: list[Recording], names: list[Any], episodes: np.ndarray, times: np.ndarray) -> np.ndarray | None:
    """Each frame's time on the messages' clock (s, as live lines' ``stamp``): its recording's start (a bag's first
    message, ns) plus its ``time``; None where the recordings are not messages. ``episodes`` index ``names``."""
    starts = {str(r.episode[0]): r.resolved.get("clock_start") for r in recordings if r.episode.len()}
    if not starts or None in starts.values():
        return None
    start = np.array([starts[str(name)] for name in names], dtype=np.int64)[episodes]
    return (start + np.round(np.asarray(times, dtype=np.float64) * 1e9).astype(np.int64)) / 1e9


def row_where(recording: Recording, index: int) -> str:
    row = int(recording.row[index]) if recording.row is not None else index
    return recording.where.format(file=recording.path, row=row)


# ---- the table reader ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Collected:
    """What a collection made: the frames table, its metadata and the files it was read from."""

    frames: pl.DataFrame
    meta: dict[str, Any]
    inputs: tuple[Path, ...] = ()
    class_order: str = "the dataset's own order"  # how the classes got their label order, in words

    @property
    def classes_line(self) -> str:
        """The classes in label order (label 0 first) and how that order was chosen: one line for the user."""
        return f"classes in label order ({self.class_order}): {', '.join(self.meta['classes'])}"


def clicked_episodes(clicks: Iterable[Iterable[int]]) -> list[int]:
    """The episodes labelled by clicks, in order, from frames.parquet's metadata ``clicks`` (episode, frame, class)."""
    return list(dict.fromkeys(int(episode) for episode, _, _ in sorted(map(tuple, clicks))))


def given(recordings: list[Recording], table: pl.DataFrame, order: np.ndarray, names: list) -> dict[str, Any]:
    """What a labels file gave ``recordings`` (``intervals.apply``'s), as frames.parquet's metadata keeps it
    (``table``: its frames in the recordings' order taken by ``order``; ``names``: its episodes' ids): the episodes
    it labelled (``labels_file_episodes``) and its clicks (``clicks``: episode, frame, class; the rest filled from
    them)."""
    given: dict[str, Any] = {}
    by_file = {str(e) for r in recordings if r.resolved.get("labels_file") for e in r.episode.unique().to_list()}
    if by_file:
        given["labels_file_episodes"] = [name for name in names if str(name) in by_file]
    clicked = np.concatenate([np.isin(np.arange(r.features.height), r.resolved.get("clicks", []))
                              for r in recordings])[order]
    if clicked.any():  # one click per phase: which labels were given, the rest filled
        given["clicks"] = [list(map(int, row)) for row in table.filter(pl.Series(clicked))
                           .select("episode", "frame", "label").rows()]
    return given


def split_by_position(n_frames: int, train_frames: int) -> np.ndarray:
    """The first ``train_frames`` frames train, the rest test."""
    return np.where(np.arange(n_frames) < train_frames, "train", "test")
