"""Why a frame got its class: the terms of its margin, as users read them (`mlnseq explain`, `predict --explain`,
`stream --explain`, ``Recognizer.explain``).

The margin is the log-ratio of the chosen class's score to another's (the runner-up, or a class named), and the
terms add up to it: each formula (weight x the difference of its true groundings with the two classes), the
network (its weight x the difference of its log-probabilities), the start distribution at a chain's first frame,
the past (the forward message: what the frames before carry in) and, with a lag or offline, the future (the
backward message over the frames the decision waited for). A hard rule that removed a class is a term without a
number. stages/explaining/explainer.py computes them; docs/explain.md reads one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any


class TermKind(StrEnum):
    """What a term of a margin comes from."""

    FORMULA = "formula"
    NETWORK = "network"
    START = "start"
    PAST = "past"
    FUTURE = "future"
    HARD_RULE = "hard-rule"


@dataclass(frozen=True)
class Term:
    """One term of a margin; a hard rule's has no contribution (it removed the class ``removed``)."""

    kind: TermKind
    text: str
    contribution: float | None
    line: int | None = None  # where it was written, for a formula or a rule
    file: str | None = None
    weight: float | None = None
    truth: tuple[int, int] | None = None  # a formula's true groundings with the chosen class and with the other
    written: str | None = None  # the line as written in its file
    removed: str | None = None  # a hard rule: the class it removed
    size: float = field(init=False, repr=False, compare=False)  # |contribution|, a hard rule's inf: for sorting

    def __post_init__(self) -> None:
        object.__setattr__(self, "size", float("inf") if self.contribution is None else abs(self.contribution))

    def record(self) -> dict[str, Any]:
        """The term as JSON: kind, text, line, contribution, and what else it has."""
        out: dict[str, Any] = {"kind": str(self.kind), "text": self.text, "line": self.line,
                               "contribution": self.contribution}
        extra = {"file": self.file, "weight": self.weight, "truth": None if self.truth is None else list(self.truth),
                 "written": self.written, "removed": self.removed}
        out.update({key: value for key, value in extra.items() if value is not None})
        return out


@dataclass(frozen=True)
class Explanation:
    """A decided frame's margin and its terms, largest first (hard rules first of all)."""

    row: int  # the frame's row in the recording (or the stream)
    episode: Any
    frame: int  # within its episode
    chosen: str
    versus: str | None  # None: no other class was possible
    margin: float | None  # None: the other class was removed by a hard rule (or none was possible)
    terms: tuple[Term, ...]
    decoder: str  # METHOD+DECODER, and how its messages were taken
    time: float | None = None
    notes: tuple[str, ...] = field(default=())

    def total(self) -> float:
        """The sum of the terms' contributions (the margin, to rounding)."""
        return float(sum(term.contribution for term in self.terms if term.contribution is not None))

    def largest(self, count: int) -> list[Term]:
        """The ``count`` largest terms (hard rules count as largest)."""
        return sorted(self.terms, key=lambda term: -term.size)[:count]

    def record(self, count: int | None = None) -> dict[str, Any]:
        """The explanation as one JSON object (``count``: only the largest terms)."""
        terms = self.terms if count is None else self.largest(count)
        out = {"episode": self.episode, "frame": self.frame, "time": self.time, "class": self.chosen,
               "versus": self.versus, "margin": self.margin, "decoder": self.decoder,
               "terms": [term.record() for term in terms]}
        if self.notes:
            out["notes"] = list(self.notes)
        return out


def brief(terms: list[Term]) -> list[dict[str, Any]]:
    """Terms as the short JSON a per-frame column or line carries: kind, text, line, contribution."""
    return [{"kind": t.kind.value, "text": t.text, "line": t.line,
             "contribution": None if t.contribution is None else round(t.contribution, 6)} for t in terms]


class Why(list):
    """A frame's largest terms as the short JSON dicts of ``brief``, with ``json``: their JSON text (a stream line
    carries it as it is)."""

    json: str = "[]"
