"""Every source of frames behind one table (``SOURCES``), like the network types: the paper's datasets
(``fetch`` simulated in MuJoCo, ``desk`` the Taurus files), made whole by their module's ``collect``, and
recordings as they are (``table``, ``rosbag``, ``lerobot``, ``hdf5``, ``jigsaws``), each module's ``read``
turning its files into ``Recording``s that ``collect`` and ``predict`` assemble with ``mlnseq.sources.table``.

A source's module, and a format's optional library, is imported only when it is read; a missing library is
refused in one line naming the extra to install.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from mlnseq.catalog import errors
from mlnseq.catalog.errors import BadInput
from mlnseq.sources.holds import MAX_HOLD_S
from mlnseq.sources.recording import Labels, Recording, TableColumns


@dataclass(frozen=True)
class Source:
    """One entry of the source table: its ``--env`` name, the module that reads it, and what it is."""

    name: str
    module: str
    summary: str
    recordings: bool  # True: a user's recordings (module.read, collect and predict); False: a dataset (module.collect)

    def load(self) -> ModuleType:
        return importlib.import_module(self.module)


SOURCES = (
    Source("fetch", "mlnseq.sources.fetch", "Fetch pick-and-place demonstrations simulated in MuJoCo", False),
    Source("desk", "mlnseq.sources.desk", "the DESK Taurus robot's files", False),
    Source("table", "mlnseq.sources.table", "your CSV or Parquet tables", True),
    Source("rosbag", "mlnseq.sources.rosbag", "ROS 1 and ROS 2 bags, bare MCAP", True),
    Source("lerobot", "mlnseq.sources.lerobot", "LeRobot datasets (v2.0, v2.1, v3.0)", True),
    Source("hdf5", "mlnseq.sources.hdf5", "robomimic-style HDF5 demonstrations", True),
    Source("jigsaws", "mlnseq.sources.jigsaws", "JIGSAWS kinematics and transcriptions", True),
)
ENVS = tuple(source.name for source in SOURCES)
RECORDING_ENVS = tuple(source.name for source in SOURCES if source.recordings)


def source_of(env: str) -> Source:
    for source in SOURCES:
        if source.name == env:
            return source
    raise BadInput(f"unknown --env {env!r}: choose one of {', '.join(ENVS)}")
LABEL_UNITS = ("seconds", "frames")
EXTRA = "recordings"
ANNOTATIONS = ("subtask",)  # --labels STYLE: a LeRobot dataset's own annotations of that style, not a file


@dataclass(frozen=True)
class SourceOptions:
    """Options of the recording sources (each ignored by the sources it does not concern)."""

    labels: Path | None = None  # every source: a CSV/TSV of episode,start,end,label intervals
    labels_unit: str | None = None  # seconds | frames; default: seconds for rosbag, frames for the others
    topics: tuple[str, ...] = ()  # rosbag: the topics to read; default every topic with numeric fields
    rate: float | None = None  # rosbag: the clock in Hz; default the first topic's rate
    label_topic: str | None = None  # rosbag: a std_msgs/String topic whose message holds until the next
    unlabelled: str | None = None  # jigsaws and --labels: class of frames outside any interval; default: dropped
    annotations: str | None = None  # lerobot: labels from the dataset's own annotations of this style (subtask)
    max_hold: float = MAX_HOLD_S  # rosbag: the longest a tick holds a topic's or joint's value (s); None: no bound

    def __post_init__(self) -> None:
        if self.max_hold is None:  # a reading record's "no bound"
            object.__setattr__(self, "max_hold", math.inf)

    def validate(self) -> None:
        if self.annotations is not None and self.annotations not in ANNOTATIONS:
            raise BadInput(f"unknown annotation style {self.annotations!r}: mlnseq reads {', '.join(ANNOTATIONS)}")
        if self.labels_unit is not None and self.labels_unit not in LABEL_UNITS:
            raise BadInput(f"unknown --labels-unit {self.labels_unit!r}: choose seconds or frames")
        if self.rate is not None and not self.rate > 0:
            raise BadInput(f"--rate must be above 0 Hz, got {self.rate:g}")
        if not self.max_hold > 0:
            raise BadInput(f"--max-hold must be above 0 seconds (inf: hold without a bound), got {self.max_hold:g}")

    def unit(self, env: str) -> str:
        return self.labels_unit or ("seconds" if env == "rosbag" else "frames")

    def record(self, env: str) -> dict[str, Any]:
        """The options a model keeps for predict to read new recordings the same way (not the labels file)."""
        record: dict[str, Any] = {"labels_unit": self.unit(env)}
        if env == "rosbag":
            record.update(topics=list(self.topics), rate=self.rate, label_topic=self.label_topic,
                          max_hold=self.max_hold if math.isfinite(self.max_hold) else None)
        if env == "jigsaws" or self.labels is not None or self.annotations is not None:
            record["unlabelled"] = self.unlabelled
        if self.annotations is not None:
            record["annotations"] = self.annotations
        return record


def labels_option(value: Path | None) -> dict[str, Any]:
    """``--labels`` as SourceOptions fields: ``subtask`` reads a LeRobot dataset's own subtask annotations, anything
    else names a file of intervals."""
    if value is not None and str(value) in ANNOTATIONS:
        return {"annotations": str(value)}
    return {"labels": value}


def missing_extra(module: str, error: ImportError) -> BadInput:
    """The one-line refusal for a format's library ``module`` that could not be imported (``error``)."""
    return errors.missing_extra(error) or BadInput(
        f"reading this format needs {module}, which is not installed: {errors.install_hint(EXTRA)}")


def read(env: str, source: Path, columns: TableColumns, options: SourceOptions,
         label: Labels = Labels.REQUIRED) -> list[Recording]:
    """The recordings at ``source`` read as ``env`` reads them, with ``--labels`` intervals applied."""
    options.validate()
    reader = source_of(env)
    if not reader.recordings:
        raise BadInput(f"--env {env} is a dataset, not recordings: choose one of {', '.join(RECORDING_ENVS)}")
    source = Path(source)
    if not source.exists():
        raise BadInput(f"--source {source} not found")
    if options.annotations is not None and env != "lerobot":
        raise BadInput(f"--labels {options.annotations} reads a LeRobot dataset's own {options.annotations} "
                       f"annotations, but --source is read as --env {env}; give a file of intervals (a file named "
                       f"{options.annotations}: its full path)")
    # --labels replaces the own labels of the episodes it names; the others keep theirs where read (a file of
    # corrections), unless a label column is required of every recording
    own_label = label if options.labels is None or label is not Labels.REQUIRED else Labels.NONE
    recordings = reader.load().read(source, columns, options, own_label)
    if options.labels is not None:
        from mlnseq.sources import intervals

        found = intervals.read(Path(options.labels), options.labels_unit)
        recordings = intervals.apply(recordings, found, options.unit(env), options.unlabelled, columns.classes)
    return recordings
