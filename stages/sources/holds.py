"""Values held on a recording's clock: when each channel (a topic's fields, or one joint of a JointState) got a
value, where it stopped before the end, started after the beginning or went silent, and what the clock did with
each gap: a tick holds a channel's last value for at most ``max_hold`` seconds (``--max-hold``); past that the
value is missing, and a frame with a missing value is dropped, as frames without a value are before the clock
starts. A channel that sent one message only (a latched topic, such as /tf_static) is a constant: held throughout.
The bag reader (``mlnseq.sources.rosbag``) fills `Arrivals` message by message and asks `Held` for the frames to
keep and the notes, one line per topic and time, naming the channels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

MAX_HOLD_S = 2.0  # twice the period of a 1 Hz topic, the slowest a recogniser usually reads: its jitter never cuts it
STOP_PERIODS = 3  # a channel silent for this many of its own periods (and two ticks) before the end has stopped
NAMES_SHOWN = 6
GAPS_SAID = 3  # a topic's gaps said one by one; more are one line


def hold_ns(max_hold: float) -> float:
    return max_hold * 1e9 if math.isfinite(max_hold) else math.inf


class Arrivals:
    """When each of a growing number of sources (a topic's messages, or a JointState's messages naming one set of
    joints) sent: the first and last time (ns), how many times, and each silence longer than ``hold`` ns as (source,
    last message's time, the next one's). Plain Python per message: this runs once for every message of a bag."""

    def __init__(self, hold: float):
        self.hold = hold
        self.first: list[int] = []
        self.last: list[int] = []
        self.count: list[int] = []
        self.gaps: list[tuple[int, int, int]] = []

    def add(self) -> int:
        """One more source; its index."""
        self.first.append(0)
        self.last.append(0)
        self.count.append(0)
        return len(self.count) - 1

    def update(self, source: int, time: int) -> None:
        """A message of ``source`` at ``time``."""
        if self.count[source]:
            if time - self.last[source] > self.hold:
                self.gaps.append((source, self.last[source], time))
        else:
            self.first[source] = time
        self.last[source] = time
        self.count[source] += 1


@dataclass(frozen=True)
class Channel:
    """Where a feature's values come from: its topic, an `Arrivals` and the sources there that set it."""

    topic: str
    arrivals: Arrivals
    sources: tuple[int, ...]

    @property
    def first(self) -> int:
        return min(self.arrivals.first[s] for s in self.sources)

    @property
    def last(self) -> int:
        return max(self.arrivals.last[s] for s in self.sources)

    @property
    def count(self) -> int:
        return sum(self.arrivals.count[s] for s in self.sources)

    def silences(self, hold: float) -> list[tuple[int, int]]:
        """(from, to): the times between two values more than ``hold`` ns apart, whichever source sent them."""
        a = self.arrivals
        if len(self.sources) == 1:
            return [(x, y) for s, x, y in a.gaps if s == self.sources[0]]
        spans = []  # each source's runs of messages at most ``hold`` apart
        for s in self.sources:
            cuts = sorted((x, y) for c, x, y in a.gaps if c == s)
            starts, ends = [a.first[s], *(y for _, y in cuts)], [*(x for x, _ in cuts), a.last[s]]
            spans += zip(starts, ends)
        spans.sort()
        out, reached = [], spans[0][1]
        for begin, end in spans[1:]:
            if begin - reached > hold:
                out.append((reached, begin))
            reached = max(reached, end)
        return out


@dataclass(frozen=True)
class Clock:
    """A recording's clock: its ticks' times (ns), the first message read, the last, and the recording's start."""

    times: np.ndarray
    begin: int
    end: int
    start: int
    period: float


class Held:
    """The channels of the features read, on one recording's clock, with ``max_hold`` seconds."""

    def __init__(self, names: Sequence[str], channels: Sequence[Channel], clock: Clock, max_hold: float):
        self.names, self.channels, self.clock = list(names), list(channels), clock
        self.max_hold, self.hold = max_hold, hold_ns(max_hold)

    def _missing_ticks(self, k: int) -> list[tuple[str, int, int, np.ndarray]]:
        """Feature ``k``'s silences past the hold: (kind, from, to, the ticks it leaves missing)."""
        channel, times = self.channels[k], self.clock.times
        if channel.count == 1:  # latched: a constant, never stale
            return []
        spans = [("gap", a, b) for a, b in channel.silences(self.hold)]
        last = channel.last
        if self.clock.end - last > self.hold:
            spans.append(("stop", last, self.clock.end))
        out = []
        for kind, a, b in spans:
            lo = np.searchsorted(times, a + self.hold, side="right")
            hi = np.searchsorted(times, b, side="left" if kind == "gap" else "right")
            out.append((kind, a, b, np.arange(lo, hi)))
        return out

    def keep(self) -> np.ndarray:
        """Per tick: whether every feature has a value there (none held past ``max_hold``)."""
        keep = np.ones(len(self.clock.times), dtype=bool)
        for k in range(len(self.names)):
            for *_, ticks in self._missing_ticks(k):
                keep[ticks] = False
        return keep

    def notes(self, where: str) -> list[str]:
        """One line per topic and time: the channels that stop before the end, go silent past the hold or start
        after the beginning, and what the ticks did with the gap."""
        events: dict[tuple, list[str]] = {}
        dropped: dict[tuple, set[int]] = {}
        tick = max(self.clock.period, 1.0)
        for k, name in enumerate(self.names):
            channel = self.channels[k]
            first, last, count = channel.first, channel.last, channel.count
            short = name[len(channel.topic.rstrip("/")) + 1:] or name
            threshold = max(STOP_PERIODS * (last - first) / (count - 1) if count > 1 else 0.0, 2 * tick)
            for kind, a, b, ticks in self._missing_ticks(k):
                key = (channel.topic, kind, round(a / tick), round(b / tick))
                events.setdefault(key, []).append(short)
                dropped.setdefault(key, set()).update(ticks.tolist())
            if count == 1 and self.clock.end - last > 2 * tick:
                events.setdefault((channel.topic, "once", round(last / tick), 0), []).append(short)
            elif threshold < self.clock.end - last <= self.hold:
                events.setdefault((channel.topic, "held", round(last / tick), 0), []).append(short)
            if first - self.clock.begin > threshold:
                events.setdefault((channel.topic, "late", round(first / tick), 0), []).append(short)
        for topic in {key[0] for key in events}:  # a topic silent again and again: one line for all its gaps
            gaps = [key for key in events if key[0] == topic and key[1] == "gap"]
            if len(gaps) > GAPS_SAID:
                merged = (topic, "gaps", min(k[2] for k in gaps), max(k[3] for k in gaps), len(gaps))
                events[merged] = sorted({name for key in gaps for name in events.pop(key)})
                dropped[merged] = set().union(*(dropped.pop(key) for key in gaps))
        return [self._say(where, key, names, len(dropped.get(key, ())))
                for key, names in sorted(events.items(), key=lambda item: item[0][2])]  # in time order

    def _say(self, where: str, key: tuple, names: list[str], dropped: int) -> str:
        topic, kind, a, b = key[:4]
        tick = max(self.clock.period, 1.0)
        at = lambda ticks: f"{(ticks * tick - self.clock.start) / 1e9:.2f} s"  # noqa: E731
        shown = ", ".join(names[:NAMES_SHOWN]) + (f" and {len(names) - NAMES_SHOWN} more" if len(names) > NAMES_SHOWN
                                                   else "")
        verb = "" if len(names) > 1 else "s"
        held = f"held {self.max_hold:g} s (--max-hold), then missing: {dropped:,} frame{'s' * (dropped != 1)} dropped"
        if kind == "stop":
            return f"{where}: {topic} {shown} stop{verb} at {at(a)}, before the end at {at(b)}: {held}"
        if kind == "gap":
            return f"{where}: {topic} {shown} send{verb} nothing from {at(a)} to {at(b)}: {held}"
        if kind == "gaps":
            return (f"{where}: {topic} {shown} send{verb} nothing for over {self.max_hold:g} s {key[4]} times between "
                    f"{at(a)} and {at(b)}: each time {held} (a topic this slow needs a longer --max-hold)")
        if kind == "once":
            return (f"{where}: {topic} {shown} sent one message, at {at(a)} (a latched value): held to the end, "
                    "whatever --max-hold")
        if kind == "held":
            end = f"{(self.clock.end - self.clock.start) / 1e9:.2f} s"
            bound = f"within --max-hold {self.max_hold:g} s" if math.isfinite(self.max_hold) else "--max-hold inf"
            return f"{where}: {topic} {shown} stop{verb} at {at(a)}, before the end at {end}: held to the end ({bound})"
        first = f"{(self.clock.begin - self.clock.start) / 1e9:.2f} s"
        frames_start = f"{(self.clock.times[0] - self.clock.start) / 1e9:.2f} s" if len(self.clock.times) else "never"
        return (f"{where}: {topic} {shown} start{verb} at {at(a)}, after the recording's first message at {first}: "
                f"missing until then, so the frames start at {frames_start}, once every channel has a value")
