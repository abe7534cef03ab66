"""Recordings read as a model's own were read, for every command that reads them with a model (predict, explain,
review): ``ReadOptions`` (the decoder and how to read, each None: as the model's manifest remembers it, its
``reading``: env, episode, time and label columns, the source's options such as topics and rate) and ``read``, which
loads the model and reads the recordings into frames. A folder whose recordings are partly labelled (a label column
or topic in some, ``--labels`` naming some, none in others) is read with labels where a recording has them."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog.decoders import parse_decoding
from mlnseq.catalog.errors import check_choice
from mlnseq.sources import RECORDING_ENVS, SourceOptions
from mlnseq.sources.recording import Labels, Recording, TableColumns


@dataclass(frozen=True)
class ReadOptions:
    """How recordings are read and decided for a model; None: as the model's own were."""

    decode: str | None = None  # a decoder (smooth-legal@5), or the model's name with it (conflation+viterbi)
    env: str | None = None  # table, rosbag, lerobot, hdf5 or jigsaws; default: the model's (table for fetch/desk)
    label_column: str | None = None  # given: the recordings must have it
    episode_column: str | None = None
    time_column: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)  # SourceOptions fields given; the rest: the model's

    def validate(self) -> None:
        if self.decode is not None:
            parse_decoding(self.decode.rpartition("+")[2])  # a method's name (conflation+filter): checked on the model
        if self.env is not None:
            check_choice("env", self.env, RECORDING_ENVS)


@dataclass(frozen=True)
class Reading:
    """A model and recordings read as it reads them: the frames (keys and features, label -1 where a recording has
    none), their metadata (``episode_names``, ``source_files``, ...) and each frame's time."""

    model: Any  # the Recognizer
    decode: str | None  # the decoder asked for (None: the model's)
    env: str
    columns: TableColumns
    source: SourceOptions
    recordings: list[Recording]
    frames: pl.DataFrame
    meta: dict[str, Any]
    times: np.ndarray

    @property
    def names(self) -> list:
        """The recordings' own episode ids, by the frames' episode index."""
        return self.meta["episode_names"]

    def labels_named(self) -> bool:
        """Whether the recordings' labels are class names (else class indices, as a numeric column holds them)."""
        return any(r.label is not None and not r.label.dtype.is_numeric() for r in self.recordings)

    def inputs(self) -> list[Path]:
        """Every file read: the recordings' and, given, the labels file (not the model)."""
        return [*map(Path, self.meta["source_files"]), *([Path(self.source.labels)] if self.source.labels else [])]

    def episode(self, index: int) -> np.ndarray:
        """The rows of the frames of episode ``index``."""
        return np.flatnonzero(self.frames["episode"].to_numpy() == index)


def reading_of(model: Any, options: ReadOptions) -> tuple[str, TableColumns, SourceOptions, Labels]:
    """The env, columns and source options to read new recordings with: the model's (a Recognizer), overridden by
    ``options``; and whether labels are required (a named label column) or read where present."""
    kept = model.manifest.reading or {}
    env = options.env or (kept.get("env") if kept.get("env") in RECORDING_ENVS else "table")
    same = env == kept.get("env")
    pick = lambda given, key, default=None: (  # noqa: E731
        given if given is not None else (kept.get(key, default) if same else default))
    columns = TableColumns(label=pick(options.label_column, "label_column", "label"),
                           episode=pick(options.episode_column, "episode_column"),
                           time=pick(options.time_column, "time_column"),
                           features=tuple(model.features), classes=tuple(model.classes))
    names = {f.name for f in dataclasses.fields(SourceOptions)} - {"labels"}
    known = {k: (tuple(v) if isinstance(v, list) else v) for k, v in kept.items() if k in names} if same else {}
    if options.label_column is not None:  # a label column named: not the annotations the model's labels came from
        known.pop("annotations", None)
    recordings = SourceOptions(**{**known, **options.overrides})
    return env, columns, recordings, Labels.REQUIRED if options.label_column is not None else Labels.OPTIONAL


def read(model: Path, source: Path, options: ReadOptions) -> Reading:
    """Load the model file ``model`` and read the recordings at ``source`` as it reads them (``options`` overriding)."""
    from mlnseq import sources
    from mlnseq.catalog.methods import decoder_of
    from mlnseq.recognition.recognizer import Recognizer
    from mlnseq.sources.table import prediction_frames

    options.validate()
    recognizer = Recognizer.load(model)
    decode = decoder_of(options.decode, recognizer.method)
    env, columns, source_options, label = reading_of(recognizer, options)
    recordings = sources.read(env, Path(source), columns, source_options, label=label)
    frames, meta, times = prediction_frames(recordings, columns.classes)
    return Reading(recognizer, decode, env, columns, source_options, recordings, frames, meta, times)
