"""Why a segment (a run of one decided class): the terms that held it, each one's mean contribution over its frames
(against each frame's runner-up), and the transition that ended it: the next frame's explanation against the
segment's class. `predict --intervals` writes it as its ``why`` column, `predict --rerun` as a text log,
`explain --segment K` in full."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from mlnseq.explaining.frames import explain
from mlnseq.explaining.explainer import Explainer, Keys, Scores
from mlnseq.explaining.terms import Explanation, Term, TermKind
from mlnseq.timeline import sequences


MESSAGES = {TermKind.PAST: "frames before (the forward message)",
            TermKind.FUTURE: "frames after (the backward message)",
            TermKind.NETWORK: "the network", TermKind.START: "the start distribution"}


@dataclass(frozen=True)
class Segment:
    """A run of one class within an episode, and why."""

    episode: Any
    index: int  # within its episode, from 0
    chosen: str
    rows: tuple[int, int]  # its first and last row
    frames: tuple[int, int]  # its first and last frame within the episode
    held: tuple[Term, ...]  # each term's mean contribution over the segment's frames, largest first
    ended: Explanation | None  # the next frame against this segment's class (None: the episode ended)

    def why(self, count: int = 3) -> str:
        """One line: the terms that held it most and those that ended it (a CSV cell, a text log)."""
        held = [t for t in self.held if t.contribution is not None and t.contribution > 0][:count]
        said = "held by " + ("; ".join(f"{_said(t)} {t.contribution:+.2f}" for t in held) or "nothing in particular")
        if self.ended is None:
            return said + "; ended with the episode"
        pushed = [t for t in self.ended.largest(len(self.ended.terms)) if t.contribution is None or t.contribution > 0]
        ends = "; ".join(_said(t) + ("" if t.contribution is None else f" {t.contribution:+.2f}")
                         for t in pushed[:count])
        return f"{said}; ended at frame {self.ended.frame} by {self.ended.chosen}: {ends or 'the frames after'}"

    def record(self, count: int | None = None) -> dict[str, Any]:
        held = self.held if count is None else self.held[:count]
        return {"episode": self.episode, "segment": self.index, "class": self.chosen, "first_frame": self.frames[0],
                "last_frame": self.frames[1], "held_by": [t.record() for t in held],
                "ended_by": None if self.ended is None else self.ended.record(count)}


def _said(term: Term) -> str:
    where = f" (line {term.line})" if term.kind is TermKind.FORMULA and term.line is not None else ""
    return (term.text if term.kind in (TermKind.FORMULA, TermKind.HARD_RULE) else MESSAGES[term.kind]) + where


def held_by(explanations: list[Explanation]) -> tuple[Term, ...]:
    """Each term's mean contribution over ``explanations`` (a formula by its text and line, a message by its kind),
    largest first; hard rules left out."""
    totals: dict[tuple, list] = {}
    for found in explanations:
        for term in found.terms:
            if term.contribution is None:
                continue
            key = (term.kind, term.text, term.line) if term.kind is TermKind.FORMULA else (term.kind,)
            entry = totals.setdefault(key, [term, 0.0])
            entry[1] += term.contribution
    count = max(len(explanations), 1)
    means = [Term(term.kind, term.text, total / count, term.line, term.file, term.weight, None, term.written)
             if term.kind is TermKind.FORMULA else Term(term.kind, MESSAGES[term.kind], total / count)
             for term, total in totals.values()]
    return tuple(sorted(means, key=lambda t: -t.contribution))


def segments(explainer: Explainer, scores: Scores, explanations: list[Explanation], keys: Keys) -> list[Segment]:
    """The segments of a recording whose every row ``explanations`` explains, in row order."""
    found, index, previous = [], 0, None
    names = [e.chosen for e in explanations]
    episodes = list(keys.episode)
    classes = list(explainer.scoring.classes)
    for run in sequences.runs(np.asarray(episodes, dtype=object), np.asarray(names, dtype=object)):
        first, last = run.start, run.stop - 1
        index = 0 if episodes[first] != previous else index + 1
        previous = episodes[first]
        ended = None
        if last + 1 < len(names) and episodes[last + 1] == episodes[first]:
            ended = explain(explainer, scores, [last + 1], classes.index(names[first]), keys)[0]
        found.append(Segment(episodes[first], index, names[first], (first, last),
                             (int(keys.frame[first]), int(keys.frame[last])), held_by(explanations[first:last + 1]),
                             ended))
    return found
