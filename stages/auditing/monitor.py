"""The audit live, one decided frame at a time: the checks of scoring.py run as the phases come (a phase settles once
it is flicker's length long or goes on in a labelled order; one out of order, a phase past its labelled length at the
recording's pace so far, a rule broken, an unlikely stretch of the chain), and at the episode's end what only the end
tells (a phase missing, a recording that ends mid-task). `Monitor` says the first reason a recording turns suspect
for, once per episode; `Monitored` wraps a Recognizer so that every command that steps one (stream, the ROS nodes)
gets the alerts beside its frames, unchanged."""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from mlnseq.auditing import scoring
from mlnseq.auditing.profile import EDGE, Profile, model_profile, tempo
from mlnseq.auditing.scoring import Check, Kind, Reason, Segment

UNKNOWN_PACE = math.log(2.0)  # until two phases are done, a recording may be this much slower than labelled ones
LAG_S = 0.25  # seconds the monitor's own decoder waits before it decides a frame (lagged Viterbi)


@dataclass(frozen=True)
class Alert:
    """The moment a recording turned suspect: the decided frame it happened at, and the reason (its severity set)."""

    frame: int
    reason: Reason

    def record(self, profile: Profile) -> dict[str, Any]:
        """The alert as a JSON object: the reason in words, its phase, kind, severity, since which frame of the
        recording, and why (its measure against its check's allowance)."""
        reason = self.reason
        check = reason.kind.check
        unit = {Check.ORDER: "flicker lengths", Check.DURATION: "spreads", Check.RULE: "s", Check.CHAIN: "s"}[check]
        return {"alert": reason.text, "phase": profile.classes[reason.phase],
                "kind": reason.kind.value, "severity": round(reason.severity, 3), "since": reason.start,
                "why": {"check": check.value, "measure": round(reason.measure, 4),
                        "allowance": round(scoring.allowance(profile, check), 4), "unit": unit}}


class Monitor:
    """One recording at a time: ``frame`` for each decided frame (its phase, predicate values, the chain's
    log-likelihood of its step), ``finish`` at its end; each returns the Alert the moment it turns suspect, once."""

    def __init__(self, profile: Profile):
        self.profile = profile
        self.rules: dict[int, list] = {}
        for rule in profile.rules:
            self.rules.setdefault(rule.phase, []).append(rule)
        self.width = max(int(round(scoring.CHAIN_S * profile.rate)), 1)
        self.reset()

    def reset(self) -> None:
        """The next frame starts a new recording."""
        self.t = 0
        self.segments: list[Segment] = []
        self.out_of_order: Reason | None = None  # the current segment's transition reason, if unseen
        self.run_phase, self.run_start, self.run_settled = -1, 0, False
        self.seen: set[int] = set()
        self.broken: dict[Any, int] = {}  # rule -> frames of its current broken stretch
        self.window: collections.deque[float] = collections.deque(maxlen=self.width)
        self.unlikely = 0  # windows in a row below the chain's floor
        self.alerted = False

    def frame(self, phase: int, evidence: np.ndarray | None = None, likelihood: float | None = None) -> Alert | None:
        if self.alerted:
            self.t += 1
            return None
        reasons = self._settle(int(phase))
        if self.run_settled:
            reasons += self._current(int(phase), evidence)
        if likelihood is not None and self.profile.chain is not None:
            reasons += self._chain(likelihood)
        self.t += 1
        return self._alert(reasons)

    def finish(self) -> Alert | None:
        """The recording ended: a phase missing, or a recording that ends mid-task, judged."""
        if self.alerted or not self.segments:
            return None
        self._close()
        said: set[int] = set()
        return self._alert(scoring.ending_reasons(self.profile, self.segments, said))

    def _alert(self, reasons: list[Reason]) -> Alert | None:
        suspect = [r for r in (scoring.weighed(self.profile, r) for r in reasons) if r.severity >= 1.0]
        if not suspect:
            return None
        self.alerted = True
        kinds = list(Kind)
        return Alert(max(self.t - 1, 0), min(suspect, key=lambda r: (r.start, kinds.index(r.kind))))

    def _pace(self, unknown: float = 0.0) -> float:
        """The recording's pace from the phases done; until two are, at least ``unknown``."""
        done = self.segments[:-1] if self.run_settled else self.segments
        pace = tempo([(s.phase, s.frames / self.profile.rate) for s in done], self.profile.log_seconds)
        return pace if len(done) >= 2 else max(pace, unknown)

    def _close(self) -> None:
        """The current run ended: a run that never settled is counted in the segment before it."""
        if not self.run_settled and self.segments and self.run_phase >= 0:
            last = self.segments[-1]
            self.segments[-1] = Segment(last.phase, last.start, self.t)

    def _settle(self, phase: int) -> list[Reason]:
        """The frame added to the runs; a run that settles as a new segment judged for its order, and the segment
        it ends for its length."""
        if phase != self.run_phase:
            self._close()
            self.run_phase, self.run_start, self.run_settled = phase, self.t, False
            self.broken.clear()
        if self.run_settled:
            last = self.segments[-1]
            self.segments[-1] = Segment(last.phase, last.start, self.t + 1)
            return []
        frames = self.t + 1 - self.run_start
        pace = self._pace()
        if self.segments and phase == self.segments[-1].phase:
            last = self.segments[-1]
            self.segments[-1], self.run_settled = Segment(last.phase, last.start, self.t + 1), True
            return []
        onward = bool(self.segments) and (self.segments[-1].phase, phase) in self.profile.transitions \
            and phase not in self.seen
        if not (onward or frames >= scoring.brief(self.profile, pace)):
            return []
        return self._settled(phase, pace)

    def _settled(self, phase: int, pace: float) -> list[Reason]:
        profile, reasons = self.profile, []
        self.run_settled = True
        if self.segments:
            previous = self.segments[-1]
            ended = self.segments[-1] = Segment(previous.phase, previous.start, self.run_start)
            reasons += self._ended(ended, Segment(phase, self.run_start, self.t + 1), pace)
        start = self.run_start if self.segments else 0
        self.segments.append(Segment(phase, start, self.t + 1))
        self.out_of_order = None
        if len(self.segments) > 1 and (self.segments[-2].phase, phase) not in profile.transitions:
            self.out_of_order = scoring.transition_reason(profile, self.segments[-2].phase, self.segments[-1],
                                                          self.seen | {self.segments[-2].phase}, pace)[0]
        elif len(self.segments) == 1 and phase not in {o[0] for o in profile.orders}:
            reasons += [r for r in scoring.order_reasons(profile, self.segments, pace, ended=False)
                        if r.kind is Kind.MISSING]
        self.seen.update(s.phase for s in self.segments[:-1])
        return reasons

    def _ended(self, ended: Segment, after: Segment, pace: float) -> list[Reason]:
        """A segment that just ended, judged whole: longer than labelled ones at the pace of the phases done (itself
        among them), or too short (not the first; one of flicker's length only where it goes on in a labelled
        order)."""
        done = [(s.phase, s.frames / self.profile.rate) for s in self.segments]
        whole = tempo(done, self.profile.log_seconds)
        whole = whole if len(done) >= 2 else max(whole, UNKNOWN_PACE)
        spreads, at = scoring.duration_spreads(self.profile, ended.phase, ended.frames, whole)
        if spreads > 0:
            return [scoring.duration_reason(self.profile, ended, spreads, at)]
        if len(self.segments) > 1 and spreads < 0 and scoring.judged_short(self.profile, ended, after, pace):
            spreads, at = scoring.duration_spreads(self.profile, ended.phase, ended.frames, pace)
            return [scoring.duration_reason(self.profile, ended, spreads, at)] if spreads < 0 else []
        return []

    def _current(self, phase: int, evidence: np.ndarray | None) -> list[Reason]:
        """The current segment so far: out of order for long enough, longer than labelled ones, a rule broken."""
        profile, segment, reasons = self.profile, self.segments[-1], []
        pace = self._pace()
        if self.out_of_order is not None:
            measure = segment.frames / scoring.brief(profile, pace) * Check.ORDER.least
            reasons.append(replace(self.out_of_order, stop=segment.stop, measure=measure))
        spreads, at = scoring.duration_spreads(profile, segment.phase, segment.frames, self._pace(UNKNOWN_PACE))
        if spreads > 0:
            reasons.append(scoring.duration_reason(profile, segment, spreads, at))
        if evidence is not None and phase == segment.phase:
            reasons += self._rules(segment, evidence)
        return reasons

    def _rules(self, segment: Segment, evidence: np.ndarray) -> list[Reason]:
        profile = self.profile
        mean = profile.log_seconds[segment.phase]
        edge = EDGE * math.exp(mean) * profile.rate if mean is not None else 0.0
        if segment.frames <= edge:
            return []
        reasons = []
        for rule in self.rules.get(segment.phase, []):
            length = self.broken.get(rule, 0) + 1 if bool(evidence[rule.column]) != rule.holds else 0
            self.broken[rule] = length
            if length:
                at = self.t + 1 - length
                reasons.append(Reason(Kind.RULE, segment.phase, at, self.t + 1, length / profile.rate,
                                      scoring.rule_text(profile, rule, evidence[None], length)))
        return reasons

    def _chain(self, likelihood: float) -> list[Reason]:
        self.window.append(float(likelihood))
        if len(self.window) < self.width or not self.segments:
            return []
        self.unlikely = self.unlikely + 1 if np.mean(self.window) < self.profile.chain else 0
        if not self.unlikely:
            return []
        start = self.t + 1 - self.width - self.unlikely + 1
        phase = next((s.phase for s in self.segments if s.stop > start), self.segments[-1].phase)
        return [Reason(Kind.CHAIN, phase, start, self.t + 1, self.unlikely / self.profile.rate,
                       f"{self.profile.classes[phase]}: a stretch the chain finds unlikely (below "
                       f"{self.profile.chain:.2f} nats a frame over {self.profile.said(self.width)})")]


class Monitored:
    """A Recognizer whose frames also go through a Monitor: it steps, decides and finishes as the Recognizer it wraps
    (every other attribute is the Recognizer's), and ``alerts()`` hands the alerts raised since it was last called.
    The monitor judges the phases its own lagged Viterbi decoder (LAG_S, on the model's chain) decides, as the whole
    recording's Viterbi does offline, whatever the model's decoder; a model without a chain: the model's own."""

    def __init__(self, recognizer: Any, profile: Profile):
        from mlnseq.catalog.decoders import Decoder, Decoding
        from mlnseq.mln.lag_online import Online

        self.recognizer, self.profile, self.monitor = recognizer, profile, Monitor(profile)
        lag = max(int(round(LAG_S * profile.rate)), 0) if profile.timed else 25
        self.decoder = Online(len(profile.classes), Decoding(Decoder.LAGVITERBI, lag)) \
            if recognizer.decode != "none" else None
        self.stepped: dict[int, tuple[Any, Any, Any]] = {}
        self.index = 0
        self.previous: int | None = None
        self.pending: list[Alert] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.recognizer, name)

    def reset(self) -> None:
        self.recognizer.reset()
        self.monitor.reset()
        if self.decoder is not None:
            self.decoder.finish()
        self.stepped.clear()
        self.index, self.previous = 0, None

    def step(self, frame: Any, decide: bool = True) -> Any:
        prediction = self.recognizer.step(frame, decide)
        evidence, unary, pairwise = self.recognizer.stepped
        if self.decoder is None:
            self.stepped[self.index] = (evidence, None, None)
            self._judge([(p.frame, p.label) for p in prediction.final])
        else:
            self.stepped[self.index] = (evidence, unary, pairwise)
            self._judge([(f.index, f.label) for f in self.decoder.step(unary, pairwise)])
        self.index += 1
        return prediction

    def decide(self) -> tuple:
        decided = self.recognizer.decide()
        if self.decoder is None:
            self._judge([(p.frame, p.label) for p in decided])
        return decided

    def finish(self) -> list:
        final = self.recognizer.finish()
        if self.decoder is None:
            self._judge([(p.frame, p.label) for p in final])
        else:
            self._judge([(f.index, f.label) for f in self.decoder.finish()])
        alert = self.monitor.finish()
        if alert is not None:
            self.pending.append(alert)
        return final

    def alerts(self) -> list[Alert]:
        taken, self.pending = self.pending, []
        return taken

    def _judge(self, decided: list[tuple[int, int]]) -> None:
        for index, label in decided:
            evidence, unary, pairwise = self.stepped.pop(index, (None, None, None))
            likelihood = None
            if unary is not None:
                row = np.asarray(unary, dtype=np.float64)
                if pairwise is not None and self.previous is not None:
                    row = row + pairwise[self.previous]
                top = row.max()
                if np.isfinite(top) and np.isfinite(row[label]):
                    likelihood = float(row[label] - top - np.log(np.exp(row - top).sum()))
            alert = self.monitor.frame(label, evidence, likelihood)
            if alert is not None:
                self.pending.append(alert)
            self.previous = label


def monitored(recognizer: Any, where: Any) -> Monitored:
    """``recognizer`` watched by the audit profile its model file holds; a model without one is one line."""
    from mlnseq.catalog.errors import BadInput

    profile = model_profile(recognizer, where)
    if profile is None:
        raise BadInput(f"{where} holds no audit profile (exported before `mlnseq audit`): export it again with "
                       "`mlnseq export` (or `mlnseq fit`) to monitor with it")
    return Monitored(recognizer, profile)


def alert_line(alert: Alert, profile: Profile, where: dict[str, Any]) -> str:
    """An alert as the JSON line live commands write: the reason in words, then ``where`` (the episode, frame and
    time of the frame answered with it: when it was raised), then the rest of the alert."""
    import json

    record = alert.record(profile)
    return json.dumps({"alert": record.pop("alert"), **where, **record})


def alert_lines(model: Any, frames: list[Any]) -> list[str]:
    """A watched model's alerts as JSON lines, each with the episode, time and stamp of the last of the live frames
    (recognition/live.py's) published with it."""
    raised = model.alerts()
    if not raised:
        return []
    where = {} if not frames else {k: v for k, v in frames[-1].record(model.classes).items()
                                   if k in ("episode", "frame", "time", "stamp")}
    return [alert_line(alert, model.profile, where) for alert in raised]
