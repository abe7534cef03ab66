"""A recording scored against a task's profile, reason by reason: its decoded phases settled (runs shorter than
half the shortest labelled segment that do not go on in a labelled order are the decoder's flicker, counted in the
segment before them), then four checks:

- order: a phase missing, phases in an order no labelled recording has, a phase repeated, a recording that ends or
  starts mid-task (a phase out of order measured by its length over flicker's);
- duration: a phase far longer or shorter than in the labelled recordings at the recording's own pace (a recording
  slower throughout is not a failure: its pace is taken out), in spreads of log-duration (the labelled spread, and
  the decoder's error at both ends of the phase, as cross-validation measured it);
- rule: a predicate value that holds throughout a phase in every labelled recording broken for a stretch (seconds);
- chain: a stretch whose steps the chain finds less likely than any of the labelled recordings' (seconds).

Each reason's severity is its measure over its check's allowance (chosen by cross-validation on the training
recordings, calibration.py): a recording is suspect from 1 up, and its score is its largest severity. Pure numpy on
arrays: `mlnseq audit` and calibration.py call it; monitor.py runs the same checks one frame at a time."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import Enum

import numpy as np

from mlnseq.auditing.chains import Decoded
from mlnseq.auditing.profile import EDGE, Profile, tempo
from mlnseq.timeline import sequences

FLICKER = 0.5  # a run shorter than this share of the shortest labelled segment is the decoder's flicker
CHAIN_S = 0.5  # seconds the chain's log-likelihood is averaged over
SHOWN = 0.5  # reasons of at least this severity are listed
MISSING = 2.0  # a phase missing measures as a phase twice flicker's length out of order
CHAIN_ALONE = SHOWN  # the most a stretch the chain finds unlikely weighs: it is listed and ranks, never decides


class Check(Enum):
    """What a reason measures, with the least allowance (what one severity is worth without calibration)."""

    ORDER = "order"  # a phase out of order: its length over flicker's (``brief``); a phase missing: MISSING
    DURATION = "duration"  # spreads of log-duration
    RULE = "rule"  # seconds of a rule broken
    CHAIN = "chain"  # seconds of an unlikely stretch

    @property
    def least(self) -> float:
        return {Check.ORDER: 1.0, Check.DURATION: 3.0, Check.RULE: 0.25, Check.CHAIN: 0.25}[self]


class Kind(Enum):
    """What a reason is about, in the order reasons at one frame are listed."""

    MISSING = "missing"
    ORDER = "order"
    REPEATED = "repeated"
    RULE = "rule"
    LONG = "long"
    SHORT = "short"
    CHAIN = "chain"

    @property
    def check(self) -> Check:
        return {Kind.MISSING: Check.ORDER, Kind.ORDER: Check.ORDER, Kind.REPEATED: Check.ORDER, Kind.RULE: Check.RULE,
                Kind.LONG: Check.DURATION, Kind.SHORT: Check.DURATION, Kind.CHAIN: Check.CHAIN}[self]


@dataclass(frozen=True)
class Reason:
    kind: Kind
    phase: int  # the phase where it happens: the one under way when it started
    start: int  # its first frame, within the recording
    stop: int  # the frame after its last
    measure: float  # in its check's unit
    text: str  # in words, without where
    severity: float = 0.0  # the measure over the check's allowance (set by ``weighed``)


@dataclass(frozen=True)
class Audited:
    """One recording's verdict: its score, whether suspect, and its reasons (those that make it suspect first, in
    time order, then the others by severity)."""

    score: float
    suspect: bool
    reasons: tuple[Reason, ...]
    pace: float  # the recording's tempo (log ratio of its phases' durations to the labelled ones')


@dataclass(frozen=True)
class Segment:
    phase: int
    start: int
    stop: int

    @property
    def frames(self) -> int:
        return self.stop - self.start


def brief(profile: Profile, pace: float = 0.0) -> float:
    """Frames under which a run is the decoder's flicker: FLICKER of the shortest labelled segment (at least 2), at
    the recording's pace where it is slower."""
    shortest = min((s for s in profile.shortest if s is not None), default=0.0)
    return max(FLICKER * shortest * profile.rate * math.exp(max(pace, 0.0)), 2.0)


def settle(path: np.ndarray, profile: Profile) -> tuple[list[Segment], float]:
    """The decoded phases as segments, each run shorter than ``brief`` that does not go on in a labelled order
    counted in the segment before it (runs before the first settled one: in it); settled again at the recording's
    pace where it is slower; and the pace."""
    runs = [(int(path[run.start]), run.start, run.stop) for run in sequences.runs(path)]
    transitions = profile.transitions
    segments = settled(runs, brief(profile), len(path), transitions)
    pace = tempo([(s.phase, s.frames / profile.rate) for s in segments], profile.log_seconds)
    if pace > 0:
        segments = settled(runs, brief(profile, pace), len(path), transitions)
        pace = tempo([(s.phase, s.frames / profile.rate) for s in segments], profile.log_seconds)
    return segments, pace


def settled(runs: list[tuple[int, int, int]], shortest: float, end: int,
            transitions: set[tuple[int, int]]) -> list[Segment]:
    """Runs of at least ``shortest`` frames as segments, and the shorter ones that go on in a labelled order (a new
    phase after its labelled predecessor); every other run counted in the segment before it."""
    out: list[Segment] = []
    seen: set[int] = set()
    for phase, start, stop in runs:
        onward = bool(out) and (out[-1].phase, phase) in transitions and phase not in seen
        if out and (phase == out[-1].phase or (stop - start < shortest and not onward)):
            out[-1] = Segment(out[-1].phase, out[-1].start, stop)
        elif out or stop - start >= shortest or stop == end:
            out.append(Segment(phase, 0 if not out else start, stop))
            seen.add(phase)
    return out


def names(profile: Profile, phases: list[int] | tuple[int, ...]) -> str:
    return ", ".join(profile.classes[p] for p in phases)


def order_reasons(profile: Profile, segments: list[Segment], pace: float = 0.0, ended: bool = True) -> list[Reason]:
    """Phases missing, out of order or repeated, against the labelled orders; ``ended``: the recording is whole
    (live: not yet, so a phase still to come is not missing)."""
    usual, seen_pairs = profile.phases, profile.transitions
    reasons: list[Reason] = []
    said: set[int] = set()  # phases a reason names as missing
    if segments and segments[0].phase not in {o[0] for o in profile.orders}:
        first = segments[0]
        before = usual[:usual.index(first.phase)] if first.phase in usual else ()
        said.update(before)
        reasons.append(Reason(Kind.MISSING, first.phase, 0, first.stop, MISSING * Check.ORDER.least,
                              f"starts with {profile.classes[first.phase]}"
                              + (f", without {names(profile, before)} before it" if before else "")))
    seen: set[int] = set()
    shortest = brief(profile, pace)
    for k, (previous, segment) in enumerate(zip(segments, segments[1:])):
        seen.add(previous.phase)
        if (previous.phase, segment.phase) not in seen_pairs:
            reason, skipped = transition_reason(profile, previous.phase, segment, seen, pace)
            if previous.frames < shortest and k > 0:  # after a phase too brief to be one: under way, the one before
                before = segments[k - 1]
                reason = replace(reason, phase=before.phase, start=previous.start,
                                 text=f"{reason.text} (after {profile.classes[before.phase]} and a brief "
                                      f"{profile.classes[previous.phase]})")
            reasons.append(reason)
            said.update(skipped)
    if ended and segments:
        reasons += ending_reasons(profile, segments, said)
    return reasons


def ending_reasons(profile: Profile, segments: list[Segment], said: set[int]) -> list[Reason]:
    """A whole recording that ends mid-task, or lacks a phase every labelled recording has."""
    usual, last, reasons = profile.phases, segments[-1], []
    if last.phase not in {o[-1] for o in profile.orders}:
        after = usual[usual.index(last.phase) + 1:] if last.phase in usual else ()
        said.update(after)
        reasons.append(Reason(Kind.MISSING, last.phase, last.start, last.stop, MISSING * Check.ORDER.least,
                              f"ends during {profile.classes[last.phase]}"
                              + (f", without {names(profile, after)}" if after else "")))
    present = {s.phase for s in segments}
    missing = [p for p in usual if p in profile.everywhere and p not in present and p not in said]
    if missing:
        reasons.append(Reason(Kind.MISSING, segments[0].phase, 0, last.stop, MISSING * Check.ORDER.least,
                              f"no {names(profile, missing)}, which every labelled recording has"))
    return reasons


def transition_reason(profile: Profile, previous: int, segment: Segment, seen: set[int],
                      pace: float = 0.0) -> tuple[Reason, tuple]:
    """The reason a transition no labelled recording has makes (a phase again, phases skipped, or another order;
    measured by the new segment's length over flicker's), and the phases it says were skipped."""
    a, b = profile.classes[previous], profile.classes[segment.phase]
    severity = segment.frames / brief(profile, pace) * Check.ORDER.least
    usual = profile.phases
    if segment.phase in seen:
        return Reason(Kind.REPEATED, previous, segment.start, segment.stop, severity, f"{b} again after {a}"), ()
    if previous in usual and segment.phase in usual and usual.index(segment.phase) > usual.index(previous) + 1:
        skipped = usual[usual.index(previous) + 1:usual.index(segment.phase)]
        return Reason(Kind.ORDER, previous, segment.start, segment.stop, severity,
                      f"{b} after {a}, without {names(profile, skipped)}"), skipped
    return Reason(Kind.ORDER, previous, segment.start, segment.stop, severity,
                  f"{b} after {a}, an order no labelled recording has"), ()


def duration_spreads(profile: Profile, phase: int, frames: float, pace: float) -> tuple[float, float]:
    """Signed spreads of log-duration of a segment of ``frames`` from its phase's labelled mean (0 for a phase never
    labelled), and the pace it is judged at: longer than the labelled ones at the recording's
    pace ``pace`` where it is slower than them, shorter than the labelled ones at their own pace (or the recording's
    where it is faster): a slower demonstration is not a failure."""
    mean = profile.log_seconds[phase]
    if mean is None or frames <= 0:
        return 0.0, 0.0
    deviation = math.log(frames / profile.rate) - mean
    at = max(pace, 0.0) if deviation > 0 else min(pace, 0.0)
    misplaced = profile.boundary * profile.rate / frames  # a decoded boundary's error, relative to the phase's length
    return (deviation - at) / math.sqrt(profile.spread[phase] ** 2 + 2 * misplaced ** 2), at


def duration_reasons(profile: Profile, segments: list[Segment], pace: float) -> list[Reason]:
    """Segments far longer or shorter than their phase's labelled ones at the recording's pace ``pace``. The first
    and last segments are not judged short (where a recording starts and ends may cut them)."""
    reasons = []
    for k, segment in enumerate(segments):
        severity, at = duration_spreads(profile, segment.phase, segment.frames, pace)
        judged = severity > 0 or (0 < k < len(segments) - 1 and judged_short(profile, segment, segments[k + 1], pace))
        if abs(severity) >= SHOWN * Check.DURATION.least and judged:
            reasons.append(duration_reason(profile, segment, severity, at))
    return reasons


def judged_short(profile: Profile, segment: Segment, after: Segment, pace: float) -> bool:
    """Whether a segment may be judged too short: one shorter than flicker's length only where it goes on in a
    labelled order (one followed by disorder is the decoder's, counted with it)."""
    return segment.frames >= brief(profile, pace) or (segment.phase, after.phase) in profile.transitions


def duration_reason(profile: Profile, segment: Segment, severity: float, pace: float) -> Reason:
    phase = profile.classes[segment.phase]
    ratio = math.exp(math.log(segment.frames / profile.rate) - profile.log_seconds[segment.phase] - pace)
    paced = " at this recording's pace" if abs(pace) > 0.1 else ""
    lasts = f"{phase} lasts {profile.said(segment.frames)}"
    if severity > 0:
        return Reason(Kind.LONG, segment.phase, segment.start, segment.stop, severity,
                      f"{lasts}, {ratio:.1f} times as long as labelled ones{paced}")
    return Reason(Kind.SHORT, segment.phase, segment.start, segment.stop, -severity,
                  f"{lasts}, {1 / ratio:.1f} times shorter than labelled ones{paced}")


def longest_run(mask: np.ndarray) -> tuple[int, int]:
    """(start, length) of the longest run of True in ``mask`` ((0, 0) when none)."""
    if not mask.any():
        return 0, 0
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    k = int(np.argmax(stops - starts))
    return int(starts[k]), int(stops[k] - starts[k])


def rule_reasons(profile: Profile, segments: list[Segment], path: np.ndarray, evidence: np.ndarray) -> list[Reason]:
    """Each segment's longest stretch (within its inner frames, where it is decoded as its phase) breaking a rule
    of its phase; one reason per predicate and segment."""
    by_phase: dict[int, list] = {}
    for rule in profile.rules:
        by_phase.setdefault(rule.phase, []).append(rule)
    reasons = []
    for segment in segments:
        rules = by_phase.get(segment.phase, [])
        if not rules:
            continue
        edge = max(int(round(EDGE * segment.frames)), 1) if segment.frames > 4 else 0
        inner = slice(segment.start + edge, segment.stop - edge)
        own = path[inner] == segment.phase
        worst: dict[str, Reason] = {}
        for rule in rules:
            start, length = longest_run(own & (evidence[inner, rule.column] != rule.holds))
            severity = length / profile.rate
            predicate = profile.columns[rule.column][0]
            if severity < SHOWN * Check.RULE.least or (predicate in worst and worst[predicate].measure >= severity):
                continue
            at = inner.start + start
            worst[predicate] = Reason(Kind.RULE, segment.phase, at, at + length, severity,
                                      rule_text(profile, rule, evidence[at:at + length], length))
        reasons += worst.values()
    return reasons


def rule_text(profile: Profile, rule, stretch: np.ndarray, length: int) -> str:
    predicate, value = profile.columns[rule.column]
    phase = profile.classes[rule.phase]
    seconds = profile.said(length)
    if not rule.holds:
        return f"{phase} with {predicate} {value} for {seconds}, which no labelled {phase} has"
    group = [j for j, (p, _) in enumerate(profile.columns) if p == predicate]
    counts = stretch[:, group].sum(axis=0)
    actual = profile.columns[group[int(np.argmax(counts))]][1] if counts.max() > 0 else f"not {value}"
    return f"{phase} with {predicate} {actual} for {seconds}, where every labelled {phase} has {predicate} {value}"


def windowed(values: np.ndarray, width: int) -> np.ndarray:
    """The mean of each ``width`` frames up to and including each frame (fewer at the start)."""
    sums = np.cumsum(np.concatenate([[0.0], values]))
    ends = np.arange(1, len(values) + 1)
    begins = np.maximum(ends - width, 0)
    return (sums[ends] - sums[begins]) / (ends - begins)


def first_unlikely(steps: np.ndarray, floor: float) -> int:
    """Where an unlikely window's unlikely stretch starts: its first step below ``floor`` (else its least likely)."""
    below = np.flatnonzero(steps < floor)
    return int(below[0]) if len(below) else int(np.argmin(steps))


def chain_reasons(profile: Profile, segments: list[Segment], likelihood: np.ndarray) -> list[Reason]:
    """The longest stretch whose windowed chain log-likelihood is below the least the labelled recordings showed."""
    if profile.chain is None or not len(likelihood) or not segments:
        return []
    width = max(int(round(CHAIN_S * profile.rate)), 1)
    means = windowed(likelihood, width)[width - 1:] if len(likelihood) >= width else windowed(likelihood, width)[-1:]
    start, length = longest_run(means < profile.chain)
    severity = length / profile.rate
    if severity < SHOWN * Check.CHAIN.least:
        return []
    first = start + first_unlikely(likelihood[start:start + width], profile.chain)  # its window's first such step
    phase = next(s.phase for s in segments if s.stop > first)
    low = float(means[start:start + length].min())
    return [Reason(Kind.CHAIN, phase, first, start + length + width - 1, severity,
                   f"{profile.classes[phase]}: a stretch the chain finds unlikely ({low:.2f} nats a frame over "
                   f"{profile.said(width)}, at least {profile.chain:.2f} in the labelled recordings)")]


def audit(profile: Profile, decoded: Decoded) -> Audited:
    """One recording, as the model decoded it, scored against ``profile``."""
    path = np.asarray(decoded.path)
    segments, pace = settle(path, profile)
    reasons = order_reasons(profile, segments, pace)
    reasons += duration_reasons(profile, segments, pace)
    if decoded.evidence is not None and profile.rules:
        reasons += rule_reasons(profile, segments, path, np.asarray(decoded.evidence))
    if decoded.likelihood is not None:
        reasons += chain_reasons(profile, segments, np.asarray(decoded.likelihood))
    return verdict(profile, reasons, pace)


def allowance(profile: Profile, check: Check) -> float:
    return profile.allowances.get(check.value, check.least)


def weighed(profile: Profile, reason: Reason) -> Reason:
    """A reason's severity: its measure over its check's allowance; a stretch the chain finds unlikely ranks a
    recording but never makes it suspect (CHAIN_ALONE): how unlikely a clean new recording's stretch can be is more
    than the training recordings' out-of-fold decodings show."""
    severity = reason.measure / allowance(profile, reason.kind.check)
    return replace(reason, severity=min(severity, CHAIN_ALONE) if reason.kind is Kind.CHAIN else severity)


def verdict(profile: Profile, reasons: list[Reason], pace: float) -> Audited:
    """Each reason weighed (``weighed``), the score (the largest severity), the verdict (suspect from 1) and the
    reasons in their order: the suspect ones by time (and kind, at one frame), then the others of at least SHOWN by
    severity."""
    weighed_ = [weighed(profile, r) for r in reasons]
    score = max((r.severity for r in weighed_), default=0.0)
    kinds = list(Kind)
    above = sorted((r for r in weighed_ if r.severity >= 1.0),
                   key=lambda r: (r.start, kinds.index(r.kind), -r.severity))
    below = sorted((r for r in weighed_ if SHOWN <= r.severity < 1.0), key=lambda r: -r.severity)
    return Audited(score, score >= 1.0, tuple(above + below), pace)
