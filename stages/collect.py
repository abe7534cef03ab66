"""collect: make or import the frames of one dataset into ``frames.parquet``.

Sources: ``fetch`` simulates scripted pick-and-place demonstrations in MuJoCo (see
``stages.fetch_demos``); ``desk`` imports the real DESK Taurus text files; ``table`` imports a user's
own CSV or Parquet recordings, and ``rosbag``, ``lerobot``, ``hdf5`` and ``jigsaws`` robot recordings as
they are (see ``stages.sources``), all assembled by ``stages.table_import``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from stages import artifacts, fetch_demos, sources
from stages.errors import BadInput, check_choice
from stages.sources import RECORDING_ENVS, SourceOptions, numeric_text
from stages.table_import import TableColumns, collect_frames, reading_record

ENVS = ("fetch", "desk", *RECORDING_ENVS)
DESK_CHANNELS = ("motion", "kinematics")

DESK_CLASSES = (
    "S1 approach peg",
    "S2 align and grasp",
    "S3 lift peg",
    "S4 transfer peg: get together",
    "S5 transfer peg: exchange",
    "S6 approach pole",
    "S7 align and place",
)
DESK_MOTION_FILES = ("taurus_motion_train.txt", "taurus_motion_test.txt")
DESK_KINEMATICS_FILE = "taurus_kinematics_train.txt"
# Columns of the motion files; the codes are derived data and are rebuilt by `binarize`.
DESK_MOTION_COLUMNS = (
    "arm_distance", "arm_distance_code", "left_gripper", "left_gripper_code",
    "right_gripper", "right_gripper_code", "label",
)
DESK_MOTION_FEATURES = ("arm_distance", "left_gripper", "right_gripper")
DESK_KINEMATICS_FEATURES = tuple(
    f"{arm}_{channel}"
    for arm in ("left", "right")
    for channel in ("x", "y", "z", "angle_1", "angle_2", "angle_3", "gripper_opening")
)
DESK_TRAIN_FRAMES = 1405


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

    def validate(self) -> None:
        check_choice("env", self.env, ENVS)
        if self.episodes < 1:
            raise BadInput(f"--episodes must be at least 1, got {self.episodes}")
        if self.train_frames is not None and self.train_frames < 0:
            raise BadInput(f"--train-frames must be 0 or more, got {self.train_frames}")
        if self.env in RECORDING_ENVS and self.source is None:
            raise BadInput(f"--env {self.env} needs --source PATH, the recordings to read")
        if self.env not in RECORDING_ENVS and self.recordings != SourceOptions():
            raise BadInput(f"--labels, --topics, --rate, --label-topic and --unlabelled are for recordings "
                           f"({', '.join(RECORDING_ENVS)}), not --env {self.env}")
        self.recordings.validate()
        if self.env == "desk":
            if self.source is None:
                raise BadInput("--env desk needs --source DIR, the folder of the DESK Taurus files")
            if self.channels not in DESK_CHANNELS:
                raise BadInput(f"unknown --channels {self.channels!r}: choose motion or kinematics")


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


Progress = Callable[[int, int], None]


def read_numeric_text(path: Path, n_columns: int) -> np.ndarray:
    """Read a whitespace-separated numeric text file, naming the file and line of any bad value."""
    if not path.is_file():
        raise BadInput(f"{path} not found: point --source at a folder holding it")
    return numeric_text.read_numeric_text(path, n_columns, f"{n_columns} numeric columns per line")


def _labels(values: np.ndarray, path: Path, n_classes: int) -> np.ndarray:
    bad = np.flatnonzero((values != np.round(values)) | (values < 0) | (values >= n_classes))
    if bad.size:
        raise BadInput(
            f"{path}:{bad[0] + 1}: label {values[bad[0]]:g} is outside the classes 0..{n_classes - 1}"
        )
    return values.astype(np.int16)


def _split(n_frames: int, train_frames: int) -> np.ndarray:
    return np.where(np.arange(n_frames) < train_frames, "train", "test")


def collect_desk(options: CollectOptions) -> Collected:
    """Import the DESK Taurus files: one episode per file, the paper's split by position."""
    source = Path(options.source)
    if not source.is_dir():
        raise BadInput(f"--source {source} is not a folder: point it at the DESK Taurus files")
    if options.channels == "kinematics":
        table = read_numeric_text(source / DESK_KINEMATICS_FILE, len(DESK_KINEMATICS_FEATURES) + 1)
        files = [(source / DESK_KINEMATICS_FILE, table)]
        features = DESK_KINEMATICS_FEATURES
        columns = list(range(len(features)))
    else:
        files = [(source / name, read_numeric_text(source / name, len(DESK_MOTION_COLUMNS)))
                 for name in DESK_MOTION_FILES]
        features = DESK_MOTION_FEATURES
        columns = [DESK_MOTION_COLUMNS.index(name) for name in features]

    episodes, frames, labels, values = [], [], [], []
    for episode, (path, table) in enumerate(files):
        episodes.append(np.full(len(table), episode, dtype=np.int32))
        frames.append(np.arange(len(table), dtype=np.int32))
        labels.append(_labels(table[:, -1], path, len(DESK_CLASSES)))
        values.append(table[:, columns])
    n_frames = sum(len(t) for _, t in files)
    train_frames = DESK_TRAIN_FRAMES if options.train_frames is None else options.train_frames
    stacked = np.concatenate(values)
    frame_table = artifacts.frames_table(
        {
            "episode": np.concatenate(episodes),
            "frame": np.concatenate(frames),
            "label": np.concatenate(labels),
            "split": _split(n_frames, train_frames),
        },
        {name: stacked[:, i] for i, name in enumerate(features)},
    )
    meta = {
        "source": "desk",
        "source_files": [str(path.resolve()) for path, _ in files],
        "classes": list(DESK_CLASSES),
        "features": list(features),
        "train_frames": train_frames,
    }
    return Collected(frame_table, meta, inputs=tuple(path for path, _ in files))


def collect_recordings(options: CollectOptions) -> Collected:
    """Import a user's recordings; ``train_frames``, when given, overrides their split (first K frames train)."""
    recordings = sources.read(options.env, Path(options.source), options.columns, options.recordings)
    frames, meta = collect_frames(recordings, options.columns.classes)
    if options.train_frames is not None:
        frames = frames.with_columns(split=pl.Series(_split(frames.height, options.train_frames)))
    meta["source"] = options.env
    resolved = {k: v for k, v in recordings[0].resolved.items() if k in ("topics", "rate")}
    meta["reading"] = reading_record(options.env, options.columns, **{**options.recordings.record(options.env), **resolved})
    meta["notes"] = list(dict.fromkeys(
        f"{what} left out: {', '.join(r.resolved[key])}" for r in recordings
        for key, what in (("skipped_topics", "topics without a numeric field"), ("skipped_features", "image and video features"))
        if r.resolved.get(key)))
    labels = options.recordings.labels
    inputs = (*map(Path, meta["source_files"]), *([Path(labels)] if labels is not None else []))
    return Collected(frames, meta, inputs=inputs, class_order=table_class_order(options.columns, meta["classes"]))


def table_class_order(columns: TableColumns, classes: list[str]) -> str:
    """How a table's classes were ordered: as --classes lists them, by numeric label, or by name."""
    if columns.classes:
        return "as --classes lists them"
    if classes == [str(k) for k in range(len(classes))]:
        return "numeric labels: label k is class k"
    return "label names sorted alphabetically; give --classes to choose the order"


def collect_fetch(options: CollectOptions, progress: Progress | None = None) -> Collected:
    """Simulate ``options.episodes`` Fetch demonstrations (or read them from ``options.cache``); the first
    ``train_frames`` frames form the train split."""
    controller = fetch_demos.Controller()
    demos = fetch_demos.demonstrations(options.episodes, options.seed, progress, controller, options.cache)
    steps = fetch_demos.EPISODE_STEPS
    n_frames = options.episodes * steps
    train_frames = fetch_demos.DEFAULT_TRAIN_FRAMES if options.train_frames is None else options.train_frames
    values = np.concatenate([d.observations for d in demos])
    features = list(fetch_demos.OBSERVATION_FEATURES)
    if options.goals:
        values = np.concatenate([values, np.concatenate([d.goals for d in demos])], axis=1)
        features += fetch_demos.GOAL_FEATURES
    frames = artifacts.frames_table(
        {
            "episode": np.repeat(np.arange(options.episodes), steps),
            "frame": np.tile(np.arange(steps), options.episodes),
            "label": np.concatenate([d.labels for d in demos]),
            "split": _split(n_frames, train_frames),
        },
        {name: values[:, i] for i, name in enumerate(features)},
    )
    successes = [d.success for d in demos]
    meta = {
        "source": "fetch",
        "env_id": fetch_demos.ENV_ID,
        "versions": fetch_demos.versions(),
        "classes": list(fetch_demos.CLASSES),
        "features": features,
        "train_frames": train_frames,
        "episode_steps": steps,
        "controller": asdict(controller),
        "success_rate": float(np.mean(successes)),
        "episode_success": successes,
    }
    return Collected(frames, meta)


def collect(options: CollectOptions, progress: Progress | None = None) -> Collected:
    """Make the frames of ``options.env`` (no file is written)."""
    options.validate()
    if options.env == "desk":
        return collect_desk(options)
    if options.env in RECORDING_ENVS:
        return collect_recordings(options)
    return collect_fetch(options, progress)


def run(workdir: Path, options: CollectOptions, progress: Progress | None = None) -> tuple[Path, Collected]:
    """Collect and write ``workdir/frames.parquet`` atomically."""
    collected = collect(options, progress)
    options_record = json.loads(json.dumps({k: v for k, v in asdict(options).items() if k != "cache"}, default=str))
    meta = {"options": options_record, "seed": options.seed, **collected.meta}
    path = artifacts.write_table(
        collected.frames, Path(workdir) / artifacts.FRAMES, "frames", meta, inputs=collected.inputs
    )
    return path, collected
