"""Every frame's and every segment's reasons, for `predict --explain N`: a JSON column of each frame's N largest terms,
each segment's ``why`` (the terms that held it, the transition that ended it) for the intervals and the Rerun text
log (stages/explaining/segments.py)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from mlnseq.explaining.frames import explain, scoring_of
from mlnseq.explaining.explainer import Explainer, Keys
from mlnseq.explaining.segments import Segment, segments
from mlnseq.explaining.terms import brief
from mlnseq.fusion.fuse import EPSILON
from mlnseq.recognition.recognizer import Recognizer


@dataclass(frozen=True)
class Reasons:
    """Per frame, its N largest terms as JSON; per segment, why."""

    frames: list[str]
    segments: list[Segment]
    count: int

    def why(self) -> list[str]:
        """Each segment's why, in row order (the rows of `intervals.segments`)."""
        return [segment.why(self.count) for segment in self.segments]

    def logged(self, times: Any) -> list[tuple[Any, float, int, str]]:
        """(episode, time, frame, why) of each segment's first frame: the Rerun recording's text log."""
        return [(s.episode, float(times[s.rows[0]]), s.frames[0], f"{s.chosen}: {s.why(self.count)}")
                for s in self.segments]


def reasons(model: Recognizer, keys: Keys, count: int) -> Reasons:
    """The reasons of the recording ``model.predict`` decided last (``keys``: where each of its rows is)."""
    scores = model.last
    explainer = Explainer(scoring_of(model, scores.decode, EPSILON))
    explanations = explain(explainer, scores, list(range(len(scores.path))), None, keys)
    return Reasons([json.dumps(brief(found.largest(count))) for found in explanations],
                   segments(explainer, scores, explanations, keys), count)
