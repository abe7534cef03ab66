"""The DESK Taurus files (the paper's real robot): one episode per motion file, the paper's split by position."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.sources import numeric_text
from mlnseq.sources.recording import Collected, split_by_position

CHANNELS = ("motion", "kinematics")

CLASSES = (
    "S1 approach peg",
    "S2 align and grasp",
    "S3 lift peg",
    "S4 transfer peg: get together",
    "S5 transfer peg: exchange",
    "S6 approach pole",
    "S7 align and place",
)
MOTION_FILES = ("taurus_motion_train.txt", "taurus_motion_test.txt")
KINEMATICS_FILE = "taurus_kinematics_train.txt"
# Columns of the motion files; the codes are derived data and are rebuilt by `binarize`.
MOTION_COLUMNS = (
    "arm_distance", "arm_distance_code", "left_gripper", "left_gripper_code",
    "right_gripper", "right_gripper_code", "label",
)
MOTION_FEATURES = ("arm_distance", "left_gripper", "right_gripper")
KINEMATICS_FEATURES = tuple(
    f"{arm}_{channel}"
    for arm in ("left", "right")
    for channel in ("x", "y", "z", "angle_1", "angle_2", "angle_3", "gripper_opening")
)
TRAIN_FRAMES = 1405


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


def collect(options: Any, progress: Any = None) -> Collected:
    """Import the DESK Taurus files at ``options.source`` (``options.channels``, ``options.train_frames``)."""
    source = Path(options.source)
    if not source.is_dir():
        raise BadInput(f"--source {source} is not a folder: point it at the DESK Taurus files")
    if options.channels == "kinematics":
        table = read_numeric_text(source / KINEMATICS_FILE, len(KINEMATICS_FEATURES) + 1)
        files = [(source / KINEMATICS_FILE, table)]
        features = KINEMATICS_FEATURES
        columns = list(range(len(features)))
    else:
        files = [(source / name, read_numeric_text(source / name, len(MOTION_COLUMNS)))
                 for name in MOTION_FILES]
        features = MOTION_FEATURES
        columns = [MOTION_COLUMNS.index(name) for name in features]

    episodes, frames, labels, values = [], [], [], []
    for episode, (path, table) in enumerate(files):
        episodes.append(np.full(len(table), episode, dtype=np.int32))
        frames.append(np.arange(len(table), dtype=np.int32))
        labels.append(_labels(table[:, -1], path, len(CLASSES)))
        values.append(table[:, columns])
    n_frames = sum(len(t) for _, t in files)
    train_frames = TRAIN_FRAMES if options.train_frames is None else options.train_frames
    stacked = np.concatenate(values)
    frame_table = artifacts.frames_table(
        {
            "episode": np.concatenate(episodes),
            "frame": np.concatenate(frames),
            "label": np.concatenate(labels),
            "split": split_by_position(n_frames, train_frames),
        },
        {name: stacked[:, i] for i, name in enumerate(features)},
    )
    meta = {
        "source": "desk",
        "source_files": [str(path.resolve()) for path, _ in files],
        "classes": list(CLASSES),
        "features": list(features),
        "train_frames": train_frames,
    }
    return Collected(frame_table, meta, inputs=tuple(path for path, _ in files))
