"""JIGSAWS-style recordings: ``kinematics/AllGestures/TRIAL.txt`` (whitespace-separated, one row a frame)
with ``transcriptions/TRIAL.txt`` (``start end gesture``, frames from 1, inclusive); one episode a trial.

The 76 kinematic variables are named as the dataset's readme lists them: per manipulator (the left and
right master tool manipulators, then the left and right patient-side ones) position, rotation matrix,
linear and angular velocity and gripper angle. A file of another width gets ``k1``, ``k2``, ...
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog.errors import BadInput
from mlnseq.sources import intervals
from mlnseq.sources.numeric_text import read_numeric_text
from mlnseq.sources.table import check_features
from mlnseq.sources.recording import Labels, Recording, TableColumns

MANIPULATORS = ("mtm_left", "mtm_right", "psm_left", "psm_right")
VARIABLES = ("x", "y", "z", *(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)),
             "vx", "vy", "vz", "wx", "wy", "wz", "gripper")
FEATURES = tuple(f"{m}_{v}" for m in MANIPULATORS for v in VARIABLES)
RATE = 30.0  # Hz: the dataset's kinematics rate, giving each frame its time in seconds
KINEMATICS, TRANSCRIPTIONS = Path("kinematics") / "AllGestures", Path("transcriptions")


def read_kinematics(path: Path) -> np.ndarray:
    return read_numeric_text(path, None, "one frame of kinematics per line")


def read(source: Path, columns: TableColumns, options, label: Labels = Labels.REQUIRED) -> list[Recording]:
    """Every trial of a JIGSAWS task folder; labelled from its transcription (``with_labels``), frames
    outside every gesture dropped or given ``options.unlabelled``; a trial without a transcription is unlabelled
    (collect: ``Labels.SOME``; predict: then all must be). ``label``: required, some, optional or none."""
    folder = Path(source) / KINEMATICS
    if not folder.is_dir():
        raise BadInput(f"--source {source}: no {KINEMATICS} folder; point it at a JIGSAWS task folder "
                       "(kinematics/AllGestures/*.txt, transcriptions/*.txt)")
    files = sorted(folder.glob("*.txt"))
    if not files:
        raise BadInput(f"{folder} holds no .txt kinematics file")
    recordings = []
    for path in files:
        values = read_kinematics(path)
        names = FEATURES if values.shape[1] == len(FEATURES) else tuple(f"k{i + 1}" for i in range(values.shape[1]))
        table = pl.DataFrame({n: values[:, i] for i, n in enumerate(names)})
        if columns.features:
            missing = [n for n in columns.features if n not in names]
            if missing:
                raise BadInput(f"{path}: no variable {', '.join(map(repr, missing))}; its variables are "
                               f"{', '.join(names[:6])}, ...")
            table = table.select(columns.features)
        rows = pl.int_range(1, len(values) + 1, eager=True)
        recording = Recording(path=path, features=check_features(table, path, "{file}:{row}", rows),
                              episode=pl.Series([path.stem] * len(values)), time=(rows - 1) / RATE, row=rows,
                              where="{file}:{row}")
        transcript = Path(source) / TRANSCRIPTIONS / path.name
        if not transcript.is_file() and label is Labels.SOME:  # a trial without a transcription: unlabelled
            recording.resolved["unlabelled"] = f"{path}: no transcription {transcript}"
        elif label is Labels.REQUIRED or (label is not Labels.NONE and transcript.is_file()):
            if not transcript.is_file():
                raise BadInput(f"{path}: no transcription {transcript}; label every trial, or leave it out")
            found = intervals.transcription(transcript, first_frame=1)
            recording = intervals.apply([recording], {path.stem: intervals.in_order(found)}, "frames",
                                        options.unlabelled)[0]
        recordings.append(recording)
    return recordings
