"""collect: make or import the frames of one dataset into ``frames.parquet``.

Sources: ``fetch`` simulates scripted pick-and-place demonstrations in MuJoCo (see
``mlnseq.sources.fetch``); ``desk`` imports the real DESK Taurus text files; ``table`` imports a user's
own CSV or Parquet recordings, and ``rosbag``, ``lerobot``, ``hdf5`` and ``jigsaws`` robot recordings as
they are (see ``mlnseq.sources``), all assembled by ``mlnseq.sources.table``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import polars as pl

from mlnseq import sources
from mlnseq.sources import desk
from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput, check_choice
from mlnseq.catalog.notes import counted
from mlnseq.labelling.alignment import Aligned
from mlnseq.labelling.estimates import estimated
from mlnseq.sources import ENVS, RECORDING_ENVS, SourceOptions
from mlnseq.sources.recording import Collected, Labels, TableColumns, split_by_position
from mlnseq.sources.splits import Holdout
from mlnseq.sources.table import collect_frames


@dataclass(frozen=True)
class CollectOptions:
    """Options of `mlnseq collect`; env-specific ones are ignored by the other env."""

    env: str = "fetch"
    source: Path | None = None  # desk: folder with the DESK text files
    channels: str = "motion"  # desk: motion (3 channels, all frames) | kinematics (14, training file)
    episodes: int = 400  # fetch: 400 episodes of 50 steps, about 20,000 frames as in the paper
    seed: int = 0
    train_frames: int | None = None  # first K frames train; default 126 (fetch), 1,405 (desk)
    goals: bool = False  # fetch: add achieved and desired goal to the 25 observation values
    columns: TableColumns = TableColumns()  # table: which columns are keys and features
    recordings: SourceOptions = SourceOptions()  # recording sources: labels file, topics, rate...
    cache: Path | None = None  # fetch: folder of simulated episodes to reuse (not recorded: frames are the same)
    holdout: Holdout | None = None  # recordings without a split column; None: SHARE (fit: UNLESS_FEW)
    align: bool = False  # label recordings without labels by alignment to the labelled training ones (fit: True)

    def validate(self) -> None:
        check_choice("env", self.env, ENVS)
        if self.episodes < 1:
            raise BadInput(f"--episodes must be at least 1, got {self.episodes}")
        if self.train_frames is not None and self.train_frames < 0:
            raise BadInput(f"--train-frames must be 0 or more, got {self.train_frames}")
        if self.env == "fetch" and self.source is not None:  # the default env simulates: --source would be ignored
            raise BadInput(f"--source {self.source} is for recordings, but --env is fetch (the default: simulated "
                           f"episodes); name the format with --env {', --env '.join(RECORDING_ENVS)} or --env desk")
        if self.env in RECORDING_ENVS and self.source is None:
            raise BadInput(f"--env {self.env} needs --source PATH, the recordings to read")
        if self.env not in RECORDING_ENVS and self.recordings != SourceOptions():
            raise BadInput(f"--labels, --topics, --rate, --label-topic, --max-hold and --unlabelled are for recordings "
                           f"({', '.join(RECORDING_ENVS)}), not --env {self.env}")
        self.recordings.validate()
        if self.env == "desk":
            if self.source is None:
                raise BadInput("--env desk needs --source DIR, the folder of the DESK Taurus files")
            if self.channels not in desk.CHANNELS:
                raise BadInput(f"unknown --channels {self.channels!r}: choose motion or kinematics")


Progress = Callable[[int, int], None]


def collect_recordings(options: CollectOptions) -> Collected:
    """Import a user's recordings; ``train_frames``, when given, overrides their split (first K frames train)."""
    recordings = sources.read(options.env, Path(options.source), options.columns, options.recordings, Labels.SOME)
    try:
        frames, meta = collect_frames(recordings, options.columns.classes, options.holdout or Holdout.SHARE)
    except BadInput as error:  # frames dropped where channels stopped or started late: said with the refusal
        said = [note for r in recordings for note in r.resolved.get("notes", [])]
        if not said:
            raise
        raise BadInput(f"{error}; a frame needs every channel's value, and: {'; '.join(said)}") from None
    frames, aligned = estimated(frames, meta, options.align)  # the clicks' boundaries, and alignment where asked
    if options.train_frames is not None:
        frames = frames.with_columns(split=pl.Series(split_by_position(frames.height, options.train_frames)))
    meta["source"] = options.env
    resolved = {k: v for k, v in recordings[0].resolved.items() if k in ("topics", "rate")}
    meta["reading"] = reading_record(options.env, options.columns,
                                     **{**options.recordings.record(options.env), **resolved})
    meta["notes"] = list(dict.fromkeys([
        *(f"{what} left out: {', '.join(r.resolved[key])}" for r in recordings
          for key, what in (("skipped_topics", "topics without a numeric field"),
                            ("skipped_features", "image and video features"),
                            ("empty_columns", "columns without a value"))
          if r.resolved.get(key)),
        *(note for r in recordings for note in r.resolved.get("notes", [])),  # a source's own notes
        *([unlabelled_note(len(meta["unlabelled_episodes"]), aligned)] if meta.get("unlabelled_episodes") else [])]))
    labels = options.recordings.labels
    inputs = (*map(Path, meta["source_files"]), *([Path(labels)] if labels is not None else []))
    return Collected(frames, meta, inputs=inputs, class_order=table_class_order(options.columns, meta["classes"]))


def unlabelled_note(n: int, aligned: Aligned | None = None) -> str:
    """One line on the recordings without labels: labelled by alignment (fit), or used unlabelled and why."""
    if aligned is not None and aligned.labelled:
        return aligned.said()
    unlabelled = f"{n:,} recording{'s' if n != 1 else ''} without labels: used unlabelled"
    why = f"; {aligned.said()}" if aligned is not None and aligned.right_when_left_out is not None else ""
    return f"{unlabelled} (never in a test split or a score){why}"


def reading_record(env: str, columns: TableColumns, **options: Any) -> dict[str, Any]:
    """How recordings were read, as a model remembers it for ``predict``: the env, the key columns, the
    source's own options (JSON-ready)."""
    return {"env": env, "label_column": columns.label, "episode_column": columns.episode,
            "time_column": columns.time, **{k: (str(v) if isinstance(v, Path) else v) for k, v in options.items()}}


def table_class_order(columns: TableColumns, classes: list[str]) -> str:
    """How a table's classes were ordered: as --classes lists them, by numeric label, or by name."""
    if columns.classes:
        return "as --classes lists them"
    if classes == [str(k) for k in range(len(classes))]:
        return "numeric labels: label k is class k"
    return "label names sorted alphabetically; give --classes to choose the order"


def collect(options: CollectOptions, progress: Progress | None = None) -> Collected:
    """Make the frames of ``options.env`` (no file is written)."""
    options.validate()
    source = sources.source_of(options.env)
    if source.recordings:
        return collect_recordings(options)
    return source.load().collect(options, progress)


def run(workdir: Path, options: CollectOptions, progress: Progress | None = None) -> tuple[Path, Collected]:
    """Collect and write ``workdir/frames.parquet`` atomically."""
    collected = collect(options, progress)
    options_record = json.loads(json.dumps({k: v for k, v in asdict(options).items() if k != "cache"}, default=str))
    meta = {"options": options_record, "seed": options.seed, **collected.meta}
    if (replaced := replacing_another(Path(workdir), options_record)) is not None:
        meta["notes"] = [*meta.get("notes", []), replaced]
        collected.meta["notes"] = meta["notes"]
    path = artifacts.write_table(
        collected.frames, Path(workdir) / artifacts.FRAMES, "frames", meta, inputs=collected.inputs
    )
    return path, collected


def replacing_another(workdir: Path, options_record: dict) -> str | None:
    """A note when the workdir's frames came from another source than these: they are replaced, and the files made
    from them stay until their own stages run again."""
    path = workdir / artifacts.FRAMES
    try:
        before = artifacts.read_metadata(path, "frames")["options"]
    except (BadInput, KeyError, TypeError):  # none, or not one we can read: nothing to say
        return None
    if (before.get("env"), before.get("source")) == (options_record["env"], options_record["source"]):
        return None
    others = sorted(p.name for p in workdir.iterdir() if p.name != artifacts.FRAMES and not p.name.startswith("."))
    was = f"--env {before.get('env')}" + (f" --source {before['source']}" if before.get("source") else "")
    kept = (f"; {counted(len(others), 'file')} made from those frames stay until their stages run again "
            f"({', '.join(others[:3])}{', ...' if len(others) > 3 else ''})") if others else ""
    return f"replaced {path}, which held the frames of {was}{kept}; -w DIR keeps datasets apart"
