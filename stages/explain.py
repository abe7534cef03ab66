"""explain: why a model decided what it did at a frame of a recording, exactly (docs/explain.md).

The recording is read as `predict` reads it (as the model's own recordings were read) and decided by the model's
decoder (or ``decode``); then one frame (by its frame number or its time) is explained: its margin over the
runner-up (or a class named) as the terms that add up to it (stages/explaining/explainer.py), or one segment:
the terms that held it and the transition that ended it. ``what_if`` scores the frame again with one predicate's
value changed and says whether the decision flips.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mlnseq.catalog.errors import BadInput
from mlnseq.explaining.frames import class_index, explain, scoring_of
from mlnseq.explaining.explainer import Explainer, Keys
from mlnseq.explaining.segments import Segment, segments
from mlnseq.explaining.terms import Explanation
from mlnseq.explaining.what_if import WhatIf, parse_what_if
from mlnseq.fusion.fuse import EPSILON
from mlnseq.recognition import reading
from mlnseq.recognition.reading import ReadOptions
from mlnseq.sources.recording import stamps as recording_stamps


@dataclass(frozen=True)
class ExplainOptions:
    """Options of `mlnseq explain`: one of ``frame``, ``time`` and ``segment``."""

    model: Path
    source: Path
    episode: str | None = None  # the recording's own id; default: its first episode
    frame: int | None = None  # the frame within the episode, as `predict` numbers it
    time: float | None = None  # the frame at this time (the last at or before it): from the start, or a stamp
    segment: int | None = None  # the episode's K-th decided segment, from 0
    versus: str | None = None  # the class to compare with (default: the runner-up)
    what_if: str | None = None  # PREDICATE=VALUE
    reading: ReadOptions = field(default_factory=ReadOptions)  # the decoder and how the recording is read

    def validate(self) -> None:
        given = [name for name, value in (("--frame", self.frame), ("--time", self.time), ("--segment", self.segment))
                 if value is not None]
        if len(given) != 1:
            both = f", not {' and '.join(given)}" if given else ""
            raise BadInput(f"give one of --frame T, --time S or --segment K{both}")
        for name, value in (("--frame", self.frame), ("--segment", self.segment)):
            if value is not None and value < 0:
                raise BadInput(f"{name} {value}: frames and segments count from 0")
        if self.what_if is not None and self.segment is not None:
            raise BadInput("--what-if changes one frame: give --frame or --time, not --segment")
        self.reading.validate()


@dataclass(frozen=True)
class Explained:
    """What `explain` found: the frame's explanation or the segment's, and the frame scored again (``what_if``)."""

    episode: Any
    explanation: Explanation | None = None
    segment: Segment | None = None
    what_if: Explanation | None = None
    change: WhatIf | None = None
    episodes: int = 1

    @property
    def flips(self) -> bool:
        return self.what_if is not None and self.what_if.chosen != self.explanation.chosen


def _episode(names: list, wanted: str | None) -> int:
    """The index of the episode asked for (the first by default)."""
    if wanted is None:
        return 0
    found = [i for i, name in enumerate(names) if str(name) == wanted]
    if not found:
        shown = ", ".join(map(str, names[:5])) + (", ..." if len(names) > 5 else "")
        raise BadInput(f"--episode {wanted!r}: the recording's episodes are {shown}")
    return found[0]


def _row(options: ExplainOptions, frames: np.ndarray, times: np.ndarray, stamps: np.ndarray | None) -> int:
    """The row of the episode's frame asked for by --frame or --time: the last frame at or before the time, on the
    recording's clock (seconds from its start) or, for messages, theirs (a live line's ``stamp``)."""
    if options.frame is not None:
        found = np.flatnonzero(frames == options.frame)
        if not len(found):
            raise BadInput(f"--frame {options.frame}: the episode's frames are {frames[0]}-{frames[-1]}")
        return int(found[0])
    found = (("time", _at(times, options.time)), ("stamp", _at(stamps, options.time)))
    rows = {clock: row for clock, row in found if row is not None}
    if len(set(rows.values())) == 1:
        return next(iter(rows.values()))
    spans = f"its times run {_span(times)}" + (f", its stamps {_span(stamps)}" if stamps is not None else "")
    if not rows:
        raise BadInput(f"--time {_seconds(options.time)}: outside the episode ({spans}); give a time within it")
    raise BadInput(f"--time {_seconds(options.time)} is frame {frames[rows['time']]} from the episode's start and "
                   f"frame {frames[rows['stamp']]} on its messages' clock ({spans}): give --frame")


def _at(times: np.ndarray | None, time: float) -> int | None:
    """The row of the last frame at or before ``time``; None before the first or a frame's period past the last."""
    if times is None or not len(times):
        return None
    period = float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    before = np.flatnonzero(times <= time)
    if not len(before) or (time >= times[-1] + period if period > 0 else time > times[-1]):
        return None
    return int(before[-1])


def _span(times: np.ndarray) -> str:
    return f"{_seconds(times[0])}-{_seconds(times[-1])}"


def _seconds(value: float) -> str:
    """Seconds to the microsecond, without trailing zeros or an exponent (a stamp is 1700000002.73)."""
    return f"{float(value):.6f}".rstrip("0").rstrip(".")


def run(options: ExplainOptions) -> Explained:
    """Read the model and the recording; explain the frame or segment asked for."""
    options.validate()
    read = reading.read(options.model, options.source, options.reading)
    model, decode, frames, times, names = read.model, read.decode, read.frames, read.times, read.names
    index = _episode(names, options.episode)
    rows = read.episode(index)
    features = frames[rows].select(model.features).to_numpy()
    keys = Keys([names[index]] * len(rows), frames["frame"].to_numpy()[rows], np.asarray(times, dtype=float)[rows])
    versus = class_index(model.classes, options.versus, "--versus")
    scores = model.scored(features, None, decode)
    explainer = Explainer(scoring_of(model, scores.decode, EPSILON))
    if options.segment is not None:
        found = segments(explainer, scores, explain(explainer, scores, list(range(len(rows))), None, keys), keys)
        if options.segment >= len(found):
            raise BadInput(f"--segment {options.segment}: episode {names[index]} has {len(found)} decided segments "
                           f"(0-{len(found) - 1})")
        return Explained(names[index], segment=found[options.segment], episodes=len(names))
    stamps = recording_stamps(read.recordings, names, frames["episode"].to_numpy(), times)
    row = _row(options, keys.frame, keys.time, None if stamps is None else stamps[rows])
    explanation = explain(explainer, scores, [row], versus, keys)[0]
    if options.what_if is None:
        return Explained(names[index], explanation, episodes=len(names))
    evidence_columns = list(getattr(model, "columns", []))
    change = parse_what_if(options.what_if, model.spec, evidence_columns)
    again = model.scored(features, None, decode, change.edit(model.spec, evidence_columns, row))
    flipped = model.classes[int(again.path[row])] != explanation.chosen  # then: the new class over the old one
    other = explanation.chosen if flipped else explanation.versus
    rescored = explain(Explainer(explainer.scoring), again, [row], class_index(model.classes, other), keys)
    return Explained(names[index], explanation, what_if=rescored[0], change=change, episodes=len(names))
