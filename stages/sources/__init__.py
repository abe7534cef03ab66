"""Recording formats read as they are: each module turns its files into ``table_import.Recording``s.

Not a stage: ``collect`` and ``predict`` both read through ``read`` here and assemble the recordings with
``stages.table_import``. A format's optional library is imported only inside its reader; a missing one is
refused in one line naming the extra to install.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stages.errors import BadInput
from stages.table_import import Recording, TableColumns, read_tables

RECORDING_ENVS = ("table", "rosbag", "lerobot", "hdf5", "jigsaws")
LABEL_UNITS = ("seconds", "frames")
EXTRA = "recordings"


@dataclass(frozen=True)
class SourceOptions:
    """Options of the recording sources (each ignored by the sources it does not concern)."""

    labels: Path | None = None  # every source: a CSV/TSV of episode,start,end,label intervals
    labels_unit: str | None = None  # seconds | frames; default: seconds for rosbag, frames for the others
    topics: tuple[str, ...] = ()  # rosbag: the topics to read; default every topic with numeric fields
    rate: float | None = None  # rosbag: the clock in Hz; default the first topic's rate
    label_topic: str | None = None  # rosbag: a std_msgs/String topic whose message holds until the next
    unlabelled: str | None = None  # jigsaws and --labels: class of frames outside any interval; default: dropped

    def validate(self) -> None:
        if self.labels_unit is not None and self.labels_unit not in LABEL_UNITS:
            raise BadInput(f"unknown --labels-unit {self.labels_unit!r}: choose seconds or frames")
        if self.rate is not None and not self.rate > 0:
            raise BadInput(f"--rate must be above 0 Hz, got {self.rate:g}")

    def unit(self, env: str) -> str:
        return self.labels_unit or ("seconds" if env == "rosbag" else "frames")

    def record(self, env: str) -> dict[str, Any]:
        """The options a model keeps for predict to read new recordings the same way (not the labels file)."""
        record: dict[str, Any] = {"labels_unit": self.unit(env)}
        if env == "rosbag":
            record.update(topics=list(self.topics), rate=self.rate, label_topic=self.label_topic)
        if env == "jigsaws" or self.labels is not None:
            record["unlabelled"] = self.unlabelled
        return record


def missing_extra(module: str, error: ImportError) -> BadInput:
    return BadInput(f"reading this format needs {module}, which is not installed: pip install 'mlnseq[{EXTRA}]'")


def read(env: str, source: Path, columns: TableColumns, options: SourceOptions, label: str = "required") -> list[Recording]:
    """The recordings at ``source`` read as ``env`` reads them, with ``--labels`` intervals applied.

    ``label``: required (collect), optional (predict: labels if the recordings carry them) or none.
    """
    options.validate()
    if env not in RECORDING_ENVS:
        raise BadInput(f"unknown --env {env!r}: choose one of {', '.join(RECORDING_ENVS)}")
    source = Path(source)
    if not source.exists():
        raise BadInput(f"--source {source} not found")
    own_label = "none" if options.labels is not None else label  # --labels replaces the recordings' own
    if env == "table":
        recordings = read_tables(source, columns, own_label)
    elif env == "jigsaws":
        from stages.sources import jigsaws

        recordings = jigsaws.read(source, columns, options, own_label)
    elif env == "rosbag":
        from stages.sources import rosbag

        recordings = rosbag.read(source, columns, options, own_label)
    elif env == "lerobot":
        from stages.sources import lerobot

        recordings = lerobot.read(source, columns, own_label)
    else:
        from stages.sources import hdf5

        recordings = hdf5.read(source, columns, own_label)
    if options.labels is not None:
        from stages.sources import intervals

        recordings = intervals.apply(recordings, intervals.read(Path(options.labels)), options.unit(env),
                                     options.unlabelled)
    return recordings
