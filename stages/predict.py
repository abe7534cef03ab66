"""predict: a model file over new recordings (a table, or any recording source collect reads).

The recordings are read as the model's own were read (its manifest's ``reading``: env, episode, time and
label columns, the source's options such as topics and rate); options given override it. Every frame of
every episode is recognised, and written with the user's episode id, its frame, its class name and every
class's probability. When the recordings carry labels, the eval metrics are computed too (each episode
scored as a stream: segment, frame, edit and F1@k).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts, folders
from mlnseq.catalog.decoders import parse_decoding
from mlnseq.catalog.errors import BadInput
from mlnseq.recognition import reading
from mlnseq.recognition.reading import ReadOptions
from mlnseq.recognition.recognizer import Recognizer
from mlnseq.sources import intervals
from mlnseq.sources.recording import stamps as recording_stamps
from mlnseq.timeline import metrics


@dataclass(frozen=True)
class PredictOptions:
    """Options of `mlnseq predict`; None: as the model's recordings were read."""

    model: Path
    source: Path
    output: Path | None = None  # default: SOURCE's name + .predictions.parquet, in the current folder
    reading: ReadOptions = field(default_factory=ReadOptions)  # the decoder and reading; default: the model's
    force: bool = False  # overwrite an existing output
    intervals: Path | None = None  # also write the predicted segments as episode,start,end,label
    rerun: Path | None = None  # also write a Rerun recording
    write_lerobot: Path | None = None  # also write a copy of the LeRobot dataset with the predicted subtasks
    lerobot_probabilities: bool = False  # with write_lerobot: the class probabilities as a feature too
    replace_subtasks: bool = False  # with write_lerobot: over episodes' own subtask annotations too
    explain: int = 0  # N > 0: a why column of each frame's N largest terms, each segment's why in intervals and Rerun

    def validate(self) -> None:
        if self.explain < 0:
            raise BadInput(f"--explain {self.explain}: give how many terms each frame shows (0: none)")
        self.reading.validate()
        if not self.force:
            for path in (self.output_path(), self.intervals, self.rerun):
                if path is not None and Path(path).exists():
                    raise BadInput(f"{path} exists; pass --force to overwrite it, or name another file")
        if self.write_lerobot is not None:
            from mlnseq.sources import lerobot_writer

            lerobot_writer.check_target(Path(self.source), Path(self.write_lerobot), self.force, {
                "-o": self.output_path(), "--intervals": self.intervals, "--rerun": self.rerun, "the model": self.model,
                "--labels": self.reading.overrides.get("labels")})
        elif self.lerobot_probabilities or self.replace_subtasks:
            raise BadInput("--write-lerobot-probabilities and --replace-subtasks go with --write-lerobot OUT")

    def output_path(self) -> Path:
        return Path(self.output) if self.output is not None else Path(f"{Path(self.source).stem}.predictions.parquet")


@dataclass(frozen=True)
class Predicted:
    path: Path
    table: pl.DataFrame
    metrics: dict[str, Any] | None  # with labels in the recordings
    episodes: int
    reading: dict[str, Any] = field(default_factory=dict)  # how the recordings were read
    written: tuple[Path, ...] = ()  # the intervals and Rerun files, if asked
    restarts: list[tuple[Any, int]] = field(default_factory=list)  # (episode, frame) where the chain restarted
    lerobot: Any = None  # with --write-lerobot: how many episodes got predicted subtasks, how many kept their own
    notes: tuple[str, ...] = ()  # how the recordings were read: channels held, stopped or started late


def predict(model: Recognizer, frames: pl.DataFrame, decode: str | None = None) -> tuple[pl.DataFrame, np.ndarray]:
    """Per frame of ``frames`` (keys and the model's features): its keys, label where labelled (empty where a
    recording has none), class name and probabilities; and the predicted class indices."""
    probabilities, predicted = model.predict(frames.select(model.features).to_numpy(), frames["episode"].to_numpy(),
                                             decode)
    labelled = (frames["label"] >= 0).any()
    keys = frames.select("episode", "frame", *([pl.when(pl.col("label") >= 0).then("label")] if labelled else []))
    return keys.with_columns(
        pl.Series("class", np.array(model.classes)[predicted], dtype=pl.String),
        *(pl.Series(artifacts.class_probability_column(name), probabilities[:, k], dtype=pl.Float32)
          for k, name in enumerate(model.classes)),
    ), predicted


def labelled_scores(model: Recognizer, frames: pl.DataFrame, predicted: np.ndarray) -> dict[str, Any] | None:
    """The eval metrics over the labelled recordings' frames (each scored as a stream), with how many recordings they
    are (``recordings``) of how many (``of``); None where none is labelled."""
    labels = frames["label"].to_numpy().astype(np.int64)
    rows = labels >= 0
    if not rows.any():
        return None
    episodes = frames["episode"].to_numpy()
    scores = metrics.score_method(predicted[rows], labels[rows], episodes[rows], len(model.classes), 0.5,
                                  segmental=True)
    return {**scores, "recordings": len(np.unique(episodes[rows])), "of": len(np.unique(episodes))}


def check_outputs(options: PredictOptions, inputs: list) -> None:
    """Refuse an output path that is another output or one of the inputs (even with --force)."""
    outputs = [(flag, Path(path)) for flag, path in (("-o", options.output_path()), ("--intervals", options.intervals),
                                                     ("--rerun", options.rerun)) if path is not None]
    taken: dict[Path, str] = {}
    for flag, path in outputs:
        if path.resolve() in taken:
            raise BadInput(f"{flag} {path} is also the file of {taken[path.resolve()]}: give each output its own name")
        taken[path.resolve()] = flag
    read = {Path(p).resolve() for p in inputs if p is not None}
    for flag, path in outputs:
        if path.resolve() in read:
            raise BadInput(f"{flag} {path} is an input of this prediction (the model, a recording or the labels); "
                           "name another file")


def run(options: PredictOptions) -> Predicted:
    """Read the model and the recordings; write the per-frame predictions (and metrics, given labels): every
    output to a temporary file beside it, all renamed at the end, or none (each temporary file removed)."""
    with contextlib.ExitStack() as staged:
        return _run(options, lambda final, folder=False: staged.enter_context(
            (folders.atomic_folder if folder else artifacts.atomic_path)(Path(final))))


def _run(options: PredictOptions, stage) -> Predicted:
    options.validate()
    check_outputs(options, [options.model, options.source, options.reading.overrides.get("labels")])
    read = reading.read(options.model, options.source, options.reading)
    model, env = read.model, read.env
    if options.write_lerobot is not None and env != "lerobot":
        raise BadInput(f"--write-lerobot writes LeRobot datasets, but --source {options.source} is read as --env {env}")
    check_outputs(options, read.inputs())
    frames, meta, times, names = read.frames, read.meta, read.times, read.names
    table, predicted = predict(model, frames, read.decode)
    table = table.with_columns(pl.Series("episode", names).gather(table["episode"].to_numpy()))
    if "label" in table.columns and read.labels_named():  # named labels stay names, as class is
        table = table.with_columns(pl.Series("label", model.classes, dtype=pl.String).gather(table["label"]))
    table = table.insert_column(2, pl.Series("time", np.asarray(times, dtype=np.float64)))  # the recording's own
    stamp = recording_stamps(read.recordings, names, frames["episode"].to_numpy(), times)
    if stamp is not None:  # messages (a bag): their clock too, as live lines carry it
        table = table.insert_column(3, pl.Series("stamp", stamp))
    found = None
    if options.explain:  # each frame's largest terms and each segment's why (stages/recognition/reasons.py)
        from mlnseq.explaining.explainer import Keys
        from mlnseq.recognition.reasons import reasons

        found = reasons(model, Keys(table["episode"].to_list(), table["frame"].to_numpy(), times), options.explain)
        table = table.with_columns(pl.Series("why", found.frames, dtype=pl.String))
    scores = labelled_scores(model, frames, predicted)
    decoding = parse_decoding(read.decode) if read.decode else model.decoding
    source_options = read.source
    reading_record = {"env": env, "label_column": read.columns.label, "episode_column": read.columns.episode,
                      "time_column": read.columns.time, **source_options.record(env),
                      **{k: v for k, v in read.recordings[0].resolved.items() if k in ("topics", "rate")}}
    restarts = [(names[episode] if 0 <= episode < len(names) else episode, frame) for episode, frame in model.restarts]
    path = options.output_path()
    artifacts.write_table(
        table, stage(path), "predicted",
        {"model": str(Path(options.model).resolve()), "method": model.method, "decode": decoding.name,
         "lag": decoding.lag,
         "classes": model.classes, "episodes": names, "metrics": scores, "reading": reading_record,
         "restarts": [[str(episode), frame] for episode, frame in restarts]},
        inputs=[Path(options.model), *read.inputs()],
    )
    written, lerobot = _write_beside(options, stage, model, frames, times, table, found, source_options.unit(env))
    notes = tuple(note for r in read.recordings for note in r.resolved.get("notes", []))
    return Predicted(path, table, scores, len(names), reading_record, written, restarts, lerobot=lerobot,
                     notes=notes)


def _write_beside(options: PredictOptions, stage, model: Recognizer, frames: pl.DataFrame, times: Any,
                  table: pl.DataFrame, found: Any, unit: str) -> tuple[tuple[Path, ...], Any]:
    """The outputs asked for beside the predictions: intervals, a Rerun recording, a LeRobot copy."""
    written = []
    if options.intervals is not None:
        segments = intervals.segments(table["episode"].to_list(), table["frame"].to_numpy(), times,
                                      table["class"].to_list(), unit)
        if found is not None:
            segments = segments.with_columns(pl.Series("why", found.why(), dtype=pl.String))
        # seconds to the nanosecond, never 1e-06
        segments.with_columns(pl.col(pl.Float64).round(9)).write_csv(stage(options.intervals), float_scientific=False)
        written.append(Path(options.intervals))
    if options.rerun is not None:
        from mlnseq.sources import rerun

        rerun.write(stage(options.rerun), table["episode"].to_list(), frames, times, table, list(model.features),
                    list(model.classes), None if found is None else found.logged(times))
        written.append(Path(options.rerun))
    lerobot = _write_lerobot(options, stage, table, list(model.classes)) if options.write_lerobot else None
    written += [Path(options.write_lerobot)] if lerobot else []
    return tuple(written), lerobot


def _write_lerobot(options: PredictOptions, stage, table: pl.DataFrame, classes: list[str]) -> Any:
    """The LeRobot dataset at --source copied with the predicted phases as its subtask annotations."""
    from mlnseq.sources import lerobot_writer

    predicted = lerobot_writer.Predicted.of(table, classes, options.lerobot_probabilities)
    return lerobot_writer.write(stage(options.write_lerobot, folder=True), Path(options.source), predicted,
                                options.replace_subtasks)
