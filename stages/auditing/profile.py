"""What the labelled recordings of a task look like, learned from their labels and predicates: the orders their
phases come in, how long each phase lasts (its log-duration about the recording's own pace), the rules that hold
throughout a phase in every one of them, how unlikely a stretch the chain found in them, and the threshold between
ok and suspect (set by calibration.py). A model file keeps it as ``audit.json``; ``Profile.read`` checks it."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from mlnseq.catalog.errors import BadInput
from mlnseq.timeline import sequences

PROFILE_FORMAT = 1
HOLDS = 0.99  # a rule holds on this share of a phase's inner frames, in every labelled recording
INFORMATIVE = 0.05  # a "never" rule only for a predicate value at least this common in the labelled frames
EDGE = 0.1  # the share of a phase at each end left out of its rules (labels and predicates change near boundaries)
SPREAD_FLOOR = 0.15  # the least spread of log-durations assumed (few recordings understate it)
SHRINK = 4  # a phase's spread is shrunk towards the pooled one as if this many more segments had it
TRUSTED = 0.9  # below this frame accuracy of its decoding on the training recordings, out of fold, an audit is unsure


@dataclass(frozen=True)
class Rule:
    """A predicate column's value throughout a phase, in every labelled recording."""

    phase: int  # class index
    column: int  # predicate column index
    holds: bool  # True: the column is true throughout; False: never true


@dataclass(frozen=True)
class Calibration:
    """How the allowances were chosen: the training recordings scored out of fold, how many of them would be suspect,
    and each check's highest measure among them."""

    recordings: int = 0
    flagged: int = 0
    highest: dict[str, float] = field(default_factory=dict)
    how: str = "cross-validation"  # or "in-sample" where the workdir has no folds
    accuracy: float | None = None  # the share of the training recordings' frames its decoding gets right (as how)

    @property
    def trusted(self) -> bool:
        """Whether the audit's decoding is sure enough of the phases for its verdicts (unknown: trusted)."""
        return self.accuracy is None or self.accuracy >= TRUSTED


@dataclass(frozen=True)
class Profile:
    """A task as its labelled recordings show it (classes and predicate columns in the model's order)."""

    classes: tuple[str, ...]
    columns: tuple[tuple[str, str], ...]  # each predicate column as (predicate, value)
    rate: float  # frames per second (1: the recordings' rate is unknown, and durations are said in frames)
    orders: tuple[tuple[int, ...], ...]  # each labelled recording's phases, one per segment
    log_seconds: tuple[float | None, ...]  # per class: the mean log-duration (s) of its segments; None: never seen
    shortest: tuple[float | None, ...]  # per class: its shortest segment (s)
    spread: tuple[float, ...]  # per class: the spread of log-durations about the recording's pace
    rules: tuple[Rule, ...]
    chain: float | None = None  # below this mean chain log-likelihood over a window, a stretch is unlikely
    allowances: dict[str, float] = field(default_factory=dict)  # check -> its measure at severity 1 (the threshold)
    calibration: Calibration = field(default_factory=Calibration)
    format: int = PROFILE_FORMAT
    timed: bool = True  # the rate is the recordings' own
    boundary: float = 0.0  # seconds: the RMS error of a decoded phase boundary on held-out labelled recordings

    def said(self, frames: float) -> str:
        """A duration in words: seconds, or frames where the rate is unknown."""
        return f"{frames / self.rate:.1f} s" if self.timed else f"{frames:.0f} frames"

    @property
    def phases(self) -> tuple[int, ...]:
        """The task's phases in their usual order: the most common labelled order."""
        counts: dict[tuple[int, ...], int] = {}
        for order in self.orders:
            counts[order] = counts.get(order, 0) + 1
        return max(counts, key=lambda order: (counts[order], -self.orders.index(order)))

    @property
    def transitions(self) -> set[tuple[int, int]]:
        return {(a, b) for order in self.orders for a, b in zip(order, order[1:])}

    @property
    def everywhere(self) -> set[int]:
        """The phases every labelled recording has."""
        return set.intersection(*(set(order) for order in self.orders)) if self.orders else set()

    def to_json(self) -> bytes:
        values = asdict(self)
        values["rules"] = [[r.phase, r.column, r.holds] for r in self.rules]
        return json.dumps(values, sort_keys=True, allow_nan=False).encode()

    @classmethod
    def read(cls, data: bytes, where: Any) -> Profile:
        """The profile a model file holds, every field checked; a malformed one is one line."""
        try:
            values = json.loads(data)
            profile = cls._of(values)
            profile.check()
        except (ValueError, TypeError, KeyError, IndexError, RecursionError) as error:
            raise BadInput(f"{where}: its audit profile is not one this mlnseq reads ({error}); export the model "
                           "again with `mlnseq export`") from None
        return profile

    @classmethod
    def _of(cls, values: dict[str, Any]) -> Profile:
        if values.get("format") != PROFILE_FORMAT:
            raise ValueError(f"format {values.get('format')!r}, this mlnseq reads {PROFILE_FORMAT}")
        return cls(tuple(values["classes"]), tuple((str(p), str(v)) for p, v in values["columns"]),
                   float(values["rate"]), tuple(tuple(int(c) for c in o) for o in values["orders"]),
                   tuple(None if v is None else float(v) for v in values["log_seconds"]),
                   tuple(None if v is None else float(v) for v in values["shortest"]),
                   tuple(float(v) for v in values["spread"]),
                   tuple(Rule(int(p), int(c), bool(h)) for p, c, h in values["rules"]),
                   None if values["chain"] is None else float(values["chain"]),
                   {str(k): float(v) for k, v in values["allowances"].items()},
                   Calibration(**values["calibration"]), timed=bool(values["timed"]),
                   boundary=float(values["boundary"]))

    def check(self) -> None:
        """Its fields against each other: classes, columns and rules in range, numbers finite."""
        n = len(self.classes)
        if not n or not all(isinstance(c, str) for c in self.classes):
            raise ValueError("no classes")
        if not (len(self.log_seconds) == len(self.shortest) == len(self.spread) == n):
            raise ValueError("per-class fields of another length than the classes")
        if not self.orders or any(not o or min(o) < 0 or max(o) >= n for o in self.orders):
            raise ValueError("an order of unknown classes")
        numbers = [self.rate, self.boundary, *self.allowances.values(), *self.spread,
                   *(v for v in self.log_seconds if v is not None),
                   *(v for v in self.shortest if v is not None), *([self.chain] if self.chain is not None else [])]
        if not all(math.isfinite(v) for v in numbers) or self.rate <= 0 or min(self.spread) <= 0 or self.boundary < 0:
            raise ValueError("a rate, spread or allowance that is not a finite positive number")
        if any(v <= 0 for v in self.allowances.values()):
            raise ValueError("an allowance that is not positive")
        if any(not (0 <= r.phase < n and 0 <= r.column < len(self.columns)) for r in self.rules):
            raise ValueError("a rule of an unknown phase or predicate column")

    def matches(self, classes: list[str], columns: list[str]) -> bool:
        """Whether it describes a model of these classes and predicate columns."""
        return list(self.classes) == list(classes) and [f"{p}_{v}" for p, v in self.columns] == list(columns)


def model_profile(recognizer: Any, where: Any) -> Profile | None:
    """The audit profile a model file holds (a Recognizer's), checked against its classes and predicate columns;
    None where it holds none (exported before `mlnseq audit`)."""
    if recognizer.audit is None:
        return None
    profile = Profile.read(recognizer.audit, where)
    if not profile.matches(recognizer.classes, getattr(recognizer, "columns", [])):
        raise BadInput(f"{where}: its audit profile describes other classes or predicates than its model: export it "
                       "again with `mlnseq export`")
    return profile


def segments_of(labels: np.ndarray) -> list[tuple[int, int, int]]:
    """(class, first frame, end frame) of each run of one class."""
    return [(int(labels[s.start]), s.start, s.stop) for s in sequences.runs(labels)]


@dataclass(frozen=True)
class Recording:
    """One labelled recording as a profile reads it: its phases in order, each segment's duration, and per phase the
    share of its inner frames on which each predicate column is true (none: a model without predicates)."""

    order: tuple[int, ...]
    durations: list[tuple[int, float]]  # (class, seconds) per segment
    shares: dict[int, np.ndarray]  # class -> [W]
    trues: np.ndarray | None  # [W] its frames on which each column is true
    frames: int


def recordings(labels: np.ndarray, episodes: np.ndarray, evidence: np.ndarray | None, rate: float | None
               ) -> list[Recording]:
    """The fully labelled recordings among ``labels`` (class index per frame, -1 unlabelled), grouped by
    ``episodes``."""
    out, per_second = [], rate or 1.0
    for span in sequences.runs(episodes):
        mine = labels[span]
        if (mine < 0).any():
            continue
        runs = segments_of(mine)
        shares, trues = {}, None
        if evidence is not None:
            for c in dict.fromkeys(c for c, _, _ in runs):
                rows = np.concatenate([np.arange(span.start + a + _edge(b - a), span.start + b - _edge(b - a))
                                       for k, a, b in runs if k == c])
                if rows.size:
                    shares[c] = evidence[rows].mean(axis=0)
            trues = evidence[span].sum(axis=0)
        durations = [(c, (stop - start) / per_second) for c, start, stop in runs]
        out.append(Recording(tuple(c for c, _, _ in runs), durations, shares, trues, span.stop - span.start))
    return out


def learn(labels: np.ndarray, episodes: np.ndarray, evidence: np.ndarray | None, classes: list[str],
          columns: list[tuple[str, str]], rate: float | None) -> Profile:
    """The profile of labelled recordings: ``labels`` (class index per frame, -1 unlabelled: left out), grouped by
    ``episodes``; ``evidence`` [T, W] their predicate values (None: a model without predicates, no rules)."""
    common = None if evidence is None else evidence.mean(axis=0) >= INFORMATIVE
    return profile_of(recordings(labels, episodes, evidence, rate), classes, columns, rate, common)


def profile_of(recorded: list[Recording], classes: list[str], columns: list[tuple[str, str]], rate: float | None,
               common: np.ndarray | None) -> Profile:
    """The profile of ``recorded`` (:func:`recordings`); ``common``: the columns true on INFORMATIVE of their frames
    (None: no rules)."""
    if not recorded:
        raise BadInput("no labelled recording to learn what the task looks like from")
    n, timed, rate = len(classes), rate is not None, rate or 1.0
    durations = [r.durations for r in recorded]
    logs = [[math.log(d) for r in durations for c, d in r if c == k] for k in range(n)]
    means = [float(np.mean(v)) if v else None for v in logs]
    shortest = [min((d for r in durations for c, d in r if c == k), default=None) for k in range(n)]
    rules = () if common is None else tuple(_rules(recorded, common, n))
    return Profile(tuple(classes), tuple(columns), float(rate), tuple(r.order for r in recorded), tuple(means),
                   tuple(shortest), tuple(_spreads(durations, means, n)), rules, timed=timed)


def without(recorded: list[Recording], k: int) -> tuple[list[Recording], np.ndarray | None]:
    """The recordings but the ``k``-th, and the columns true on INFORMATIVE of their frames (as :func:`learn` finds
    them on those recordings alone)."""
    others = recorded[:k] + recorded[k + 1:]
    if not others or others[0].trues is None:
        return others, None
    return others, sum(r.trues for r in others) / sum(r.frames for r in others) >= INFORMATIVE


def _edge(length: int) -> int:
    return max(int(round(EDGE * length)), 1) if length > 4 else 0


def tempo(segments: list[tuple[int, float]], means: tuple[float | None, ...] | list[float | None]) -> float:
    """A recording's pace: the median of its segments' log-durations about their class's mean (0: as the labelled
    recordings, 0.5: every phase about 1.6 times as long)."""
    deviations = [math.log(d) - means[c] for c, d in segments if means[c] is not None and d > 0]
    return float(np.median(deviations)) if deviations else 0.0


def _spreads(durations: list[list[tuple[int, float]]], means: list[float | None], n: int) -> list[float]:
    """Per class, the spread of log-durations about each recording's pace, shrunk towards the pooled spread and
    floored at SPREAD_FLOOR."""
    residuals: list[list[float]] = [[] for _ in range(n)]
    for segments in durations:
        pace = tempo(segments, means)
        for c, d in segments:
            residuals[c].append(math.log(d) - means[c] - pace)
    pooled = [r for values in residuals for r in values]
    prior = float(np.sqrt(np.mean(np.square(pooled)))) if pooled else SPREAD_FLOOR
    out = []
    for values in residuals:
        squares = float(np.sum(np.square(values)))
        out.append(max(math.sqrt((squares + SHRINK * prior**2) / (len(values) + SHRINK)), SPREAD_FLOOR))
    return out


def _rules(recorded: list[Recording], common: np.ndarray, n: int) -> list[Rule]:
    """The columns true (or never true) on at least HOLDS of each phase's inner frames in every recording that has
    the phase; a "never" rule only for a ``common`` column."""
    rules = []
    for c in range(n):
        shares = [r.shares[c] for r in recorded if c in r.shares]
        if not shares:
            continue
        share = np.stack(shares)
        rules += [Rule(c, int(j), True) for j in np.flatnonzero(share.min(axis=0) >= HOLDS)]
        rules += [Rule(c, int(j), False) for j in np.flatnonzero((share.max(axis=0) <= 1 - HOLDS) & common)]
    return rules


def calibrated_as(profile: Profile, allowances: dict[str, float], chain: float | None, calibration: Calibration,
                  boundary: float = 0.0) -> Profile:
    return replace(profile, allowances=dict(allowances), chain=chain, calibration=calibration, boundary=boundary)


def boundary_error(labels: np.ndarray, path: np.ndarray) -> list[float]:
    """Frames between each labelled segment's ends and those of the decoded segment of its phase that overlaps it
    most (a phase the decoder missed: its ends against nothing, left out)."""
    decoded = segments_of(path)
    errors = []
    for phase, start, stop in segments_of(labels):
        overlaps = [(min(stop, b) - max(start, a), a, b) for c, a, b in decoded
                    if c == phase and b > start and a < stop]
        if overlaps:
            _, a, b = max(overlaps)
            errors += [abs(a - start), abs(b - stop)]
    return errors
