"""collect: make or import the frames of one dataset into ``frames.parquet``.

Sources: ``fetch`` simulates scripted pick-and-place demonstrations in MuJoCo (see
``stages.fetch_demos``); ``desk`` imports the real DESK Taurus text files; ``table`` imports a user's
own CSV or Parquet recordings (see ``stages.table_import``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from stages import artifacts, fetch_demos
from stages.errors import BadInput, check_choice
from stages.table_import import TableColumns, import_table

ENVS = ("fetch", "desk", "table")
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
    cache: Path | None = None  # fetch: folder of simulated episodes to reuse (not recorded: frames are the same)

    def validate(self) -> None:
        check_choice("env", self.env, ENVS)
        if self.episodes < 1:
            raise BadInput(f"--episodes must be at least 1, got {self.episodes}")
        if self.train_frames is not None and self.train_frames < 0:
            raise BadInput(f"--train-frames must be 0 or more, got {self.train_frames}")
        if self.env == "table" and self.source is None:
            raise BadInput("--env table needs --source FILE or DIR, a CSV or Parquet file or a folder of them")
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


Progress = Callable[[int, int], None]


def read_numeric_text(path: Path, n_columns: int) -> np.ndarray:
    """Read a whitespace-separated numeric text file, naming the file and line of any bad value."""
    if not path.is_file():
        raise BadInput(f"{path} not found: point --source at a folder holding it")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise BadInput(f"cannot read {path}: {error}") from error
    rows: list[list[float]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != n_columns:
            raise BadInput(f"{path}:{number}: expected {n_columns} columns, found {len(fields)}")
        try:
            values = [float(field) for field in fields]
        except ValueError:
            raise BadInput(f"{path}:{number}: non-numeric value in {line.strip()[:60]!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise BadInput(f"{path}:{number}: NaN or infinite value; remove or repair that frame")
        rows.append(values)
    if not rows:
        raise BadInput(f"{path} is empty: expected {n_columns} numeric columns per line")
    return np.asarray(rows, dtype=np.float64)


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


def collect_table(options: CollectOptions) -> Collected:
    """Import a user's table; ``train_frames``, when given, overrides its split (first K frames train)."""
    frames, meta = import_table(Path(options.source), options.columns)
    if options.train_frames is not None:
        frames = frames.with_columns(split=pl.Series(_split(frames.height, options.train_frames)))
    return Collected(frames, meta, inputs=tuple(Path(name) for name in meta["source_files"]))


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
    if options.env == "table":
        return collect_table(options)
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
