"""What a fit's workdir tells `mlnseq review -w`: the recordings it was collected from and how they were read (its
labels file too), the labels fit trained on for each recording with where they came from (the recording's own, the
labels file's, estimated between clicks or by alignment), its ranking of what to label next (label_next.csv) and the
phases it proposes to correct (unlabelled.intervals.csv)."""

from __future__ import annotations

import csv
import enum
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.sources import RECORDING_ENVS, intervals
from mlnseq.sources.recording import clicked_episodes


class Origin(enum.Enum):
    """Where the labels fit trained on for a recording came from (the value: how the page says it)."""

    OWN = "its own"
    FILE = "the labels file's"
    CLICKS = "estimated between your clicks"
    ALIGNED = "estimated by alignment"

    @property
    def estimated(self) -> bool:
        return self in (Origin.CLICKS, Origin.ALIGNED)


@dataclass(frozen=True)
class FitLabels:
    """A recording's labels as fit trained on them: class names per frame (None: no label there)."""

    names: list[str | None]
    origin: Origin


@dataclass(frozen=True)
class Workdir:
    """A fit's workdir as review reads it."""

    path: Path
    source: Path  # the recordings it was collected from
    labels_file: Path | None  # fit's --labels
    labels_unit: str | None  # --labels-unit as fit was given it
    labels: dict[str, FitLabels] = field(default_factory=dict)  # by episode id, as text
    ranks: dict[str, tuple[int, str]] = field(default_factory=dict)  # label_next.csv: episode -> (rank, reason)
    proposals: dict[str, list] = field(default_factory=dict)  # unlabelled.intervals.csv: episode -> its intervals

    def reading(self, given: dict[str, Any]) -> dict[str, Any]:
        """The source overrides that read the recordings as fit read them (its labels file), unless ``given``
        names labels itself."""
        if self.labels_file is None or "labels" in given or "annotations" in given:
            return given
        return {**given, "labels": self.labels_file, "labels_unit": self.labels_unit}  # fit's (None too)

    def proposal(self, episode: str, frames: int, classes: list[str]) -> np.ndarray | None:
        """The phases fit proposes for ``episode`` to correct, as class indices per frame; None without any."""
        found = self.proposals.get(episode)
        if not found:
            return None
        labels = np.full(frames, -1, dtype=np.int64)
        for interval in found:
            if str(interval.label) in classes:
                labels[int(interval.start):int(interval.end) + 1] = classes.index(str(interval.label))
        return labels


def read(workdir: Path) -> Workdir:
    """The workdir's recordings, labels, ranking and proposals (frames.parquet must come from recordings)."""
    workdir = Path(workdir)
    frames, meta = artifacts.read_table(workdir / artifacts.FRAMES, "frames")
    options = meta.get("options") or {}
    source = options.get("source")
    if not source or meta.get("source") not in RECORDING_ENVS:
        raise BadInput(f"-w {workdir}: its frames were not collected from recordings; give --source")
    given = options.get("recordings") or {}
    labels_file = given.get("labels")
    return Workdir(workdir, Path(source), None if labels_file is None or labels_file in ("subtask",) else
                   Path(labels_file), given.get("labels_unit"), fit_labels(frames, meta), ranks_of(workdir),
                   proposals_of(workdir))


def fit_labels(frames: Any, meta: dict[str, Any]) -> dict[str, FitLabels]:
    """Each recording's labels in frames.parquet (what fit trained on) and where they came from."""
    names, classes = meta["episode_names"], np.asarray(meta["classes"], dtype=object)
    clicked = {str(names[e]) for e in clicked_episodes(meta.get("clicks", []))}
    bare = {str(name) for name in meta.get("unlabelled_episodes", [])}
    by_file = {str(name) for name in meta.get("labels_file_episodes", [])}
    found = {}
    for (episode,), part in frames.sort("episode", "frame").partition_by("episode", as_dict=True,
                                                                        maintain_order=True).items():
        name = str(names[episode])
        labels = part["label"].to_list()
        if all(k is None for k in labels):
            continue
        origin = (Origin.CLICKS if name in clicked else Origin.ALIGNED if name in bare else
                  Origin.FILE if name in by_file else Origin.OWN)
        found[name] = FitLabels([None if k is None else str(classes[k]) for k in labels], origin)
    return found


def ranks_of(workdir: Path | None) -> dict[str, tuple[int, str]]:
    """WORKDIR/label_next.csv's ranks by episode (episode, rank, reason), if the workdir has one."""
    path = None if workdir is None else Path(workdir) / artifacts.LABEL_NEXT
    if path is None or not path.is_file():
        return {}
    found = {}
    with path.open(encoding="utf-8", newline="") as handle:
        for line, row in enumerate(csv.DictReader(handle), start=2):
            try:
                found[str(row["episode"])] = (int(row["rank"]), str(row.get("reason") or ""))
            except (KeyError, TypeError, ValueError):
                raise BadInput(f"{path}:{line}: expected episode,rank,reason with a whole-number rank") from None
    return found


def proposals_of(workdir: Path) -> dict[str, list]:
    """WORKDIR/unlabelled.intervals.csv's intervals by episode (frames), if the workdir has one."""
    path = Path(workdir) / artifacts.UNLABELLED_INTERVALS
    return intervals.read(path, "frames") if path.is_file() else {}
