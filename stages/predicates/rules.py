"""The predicates' per-frame code rules and the distance channel, each written once, and the two binarizers
that evaluate them: over whole episodes (numpy arrays: the binarize stage, the recogniser's ``predict``) and
one frame at a time (plain floats: the recogniser's ``step``, a live stream).

The rules (paper section IV; the spec language is in stages/predicates/spec.py): a value's code is the
index into its predicate's ``values``.

- ``bins`` (C1): how many of the ascending ``edges`` are at most x.
- ``change`` (C2, eq. 9): d = x minus the previous x (with ``window`` W: the x W frames before, or the episode's
  first where it has fewer); increase (d > threshold), decrease (d < -threshold), else static.
- ``gripper``: open (x > ``open_above``), else closed (x < ``closed_below``), else opening / closing by
  d = x − ``previous_scale``·previous x beyond ``threshold``, else static.
- ``pair``: first's code times the number of second's values, plus second's code.

The previous frame is the row before in the same episode, ordered by frame. The first frame of an
episode has none: its change is 0 (static). The codes published with the paper compare the first two
frames of each file with themselves instead; mlnseq differs from them only on those two frames.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from mlnseq.catalog.errors import BadInput
from mlnseq.predicates.spec import Bins, Change, Distance, Gripper, Pair, Predicate, PredicateSpec

# (reads the change d rather than x, x or d above the bound (else below), bound, code)
Test = tuple[bool, bool, float, int]


def tests(predicate: Change | Gripper) -> tuple[tuple[Test, ...], int]:
    """The rule of a change or gripper predicate: its tests in order (the first that holds gives its code), and
    the code when none holds."""
    t = predicate.threshold
    if isinstance(predicate, Change):
        return ((True, True, t, 1), (True, False, -t, 2)), 0
    return ((False, True, predicate.open_above, 0), (False, False, predicate.closed_below, 1),
            (True, True, t, 2), (True, False, -t, 3)), 4


def window(predicate: Predicate) -> int:
    """How many frames back a predicate's change d looks (1: the previous frame)."""
    return predicate.window if isinstance(predicate, Change) else 1


def looked_back(value: np.ndarray, first: np.ndarray, frames: int) -> np.ndarray:
    """The value ``frames`` rows before each row in its episode (``first`` marks episodes' first rows), or the
    episode's first value where it has fewer rows before it."""
    index = np.arange(len(value))
    start = np.maximum.accumulate(np.where(first, index, 0))
    return value[np.maximum(index - frames, start)]


def previous_scale(predicate: Predicate) -> float:
    """What multiplies the previous frame's value in a predicate's change d."""
    return predicate.previous_scale if isinstance(predicate, Gripper) else 1.0


def change(value: Any, previous: Any, scale: float) -> Any:
    """d = x − scale·(the previous frame's x), on arrays or floats (the caller sets it 0 on a first frame)."""
    return value - scale * previous


def pair_code(first: Any, second: Any, n_second: int) -> Any:
    """A pair's code from its parts' codes, first-major, on arrays or ints."""
    return first * n_second + second


def distance(start: np.ndarray, end: np.ndarray, decimals: int | None) -> np.ndarray:
    """The Euclidean distance between points [..., 3], rounded to ``decimals`` when given."""
    value = np.sqrt(((end - start) ** 2).sum(axis=-1))
    return value if decimals is None else np.round(value, decimals)


# ---- whole episodes -------------------------------------------------------------------------------


def codes(predicate: Bins | Change | Gripper, value: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """The code of every frame, from its channel values and changes."""
    if isinstance(predicate, Bins):
        return np.searchsorted(np.asarray(predicate.edges), value, side="right")
    rule, otherwise = tests(predicate)
    conditions = [((delta if on_delta else value) > bound) if above else ((delta if on_delta else value) < bound)
                  for on_delta, above, bound, _ in rule]
    return np.select(conditions, [code for *_, code in rule], otherwise)


Channels = dict[str, np.ndarray]
RawChannel = Callable[[Distance | Predicate, str, str], np.ndarray]  # (entry, channel name, key) -> float64 values


def channels_of(spec: PredicateSpec, raw: RawChannel) -> Channels:
    """Every channel a predicate reads: the frames' own columns (through ``raw``) and the derived distances."""
    channels: Channels = {}

    def value(entry: Distance | Predicate, name: str, key: str) -> np.ndarray:
        if name not in channels:
            channels[name] = raw(entry, name, key)
        return channels[name]

    for derived in spec.channels:
        start = np.column_stack([value(derived, c, "from") for c in derived.start])
        end = np.column_stack([value(derived, c, "to") for c in derived.end])
        channels[derived.name] = distance(start, end, derived.decimals)
    for predicate in spec.predicates:
        if not isinstance(predicate, Pair):
            value(predicate, predicate.channel, "channel")
    return channels


def evidence(spec: PredicateSpec, channels: Channels, first: np.ndarray) -> np.ndarray:
    """[frames, columns] bool: one column per predicate value, in the spec's column order; ``first`` marks each
    episode's first frame (frames in episode order)."""
    earlier: dict[str, np.ndarray] = {}
    sizes = {p.name: len(p.values) for p in spec.predicates}
    columns = []
    for predicate in spec.predicates:
        if isinstance(predicate, Pair):
            found = pair_code(earlier[predicate.first], earlier[predicate.second], sizes[predicate.second])
        else:
            value = channels[predicate.channel]
            delta = change(value, looked_back(value, first, window(predicate)), previous_scale(predicate))
            delta[first] = 0.0
            found = codes(predicate, value, delta)
        earlier[predicate.name] = found
        columns += [found == index for index in range(len(predicate.values))]
    return np.column_stack(columns)


def missing_channel(spec: PredicateSpec, entry: Distance | Predicate, name: str, key: str, where: str,
                    known: list[str]) -> BadInput:
    hint = spec.hints.get(entry.name)
    section = "channel" if isinstance(entry, Distance) else "predicate"
    return BadInput(
        f"{spec.where(entry, key)}: key '{key}' of [[{section}]] {entry.name!r}: channel {name!r} is not in "
        f"{where} nor a [[channel]] above; " + (hint if hint else f"known channels: {', '.join(known)}")
    )


def features_evidence(spec: PredicateSpec, names: Sequence[str], features: np.ndarray, first: np.ndarray) -> np.ndarray:
    """:func:`evidence` of raw feature rows [T, F] named ``names`` (a model's), frames in episode order."""
    index = {name: i for i, name in enumerate(names)}

    def raw(entry: Distance | Predicate, name: str, key: str) -> np.ndarray:
        if name not in index:
            raise missing_channel(spec, entry, name, key, "the model's features", list(names))
        return np.asarray(features[:, index[name]], dtype=np.float64)

    return evidence(spec, channels_of(spec, raw), first)


# ---- one frame at a time --------------------------------------------------------------------------


def code(rule: tuple[tuple[Test, ...], int], value: float, delta: float) -> int:
    """:func:`codes` of a change or gripper predicate for one frame, on plain floats, from its ``tests`` (``rule``;
    a bins predicate's code is ``bisect.bisect_right(edges, value)``, as ``np.searchsorted(side="right")``)."""
    checks, otherwise = rule
    for on_delta, above, bound, found in checks:
        x = delta if on_delta else value
        if (x > bound) if above else (x < bound):
            return found
    return otherwise


class StreamingBinarizer:
    """Binarize one frame at a time, as :func:`evidence` does over a whole episode: the change and gripper
    predicates compare with the previous frame, which the first frame of an episode does not have."""

    def __init__(self, spec: PredicateSpec, features: Sequence[str]):
        self.spec = spec
        index = {name: i for i, name in enumerate(features)}
        self._raw: dict[str, int] = {}  # each feature the spec reads -> its position in a frame

        def check(entry: Distance | Predicate, name: str, key: str) -> np.ndarray:
            if name not in index:
                raise missing_channel(spec, entry, name, key, "the model's features", list(features))
            self._raw[name] = index[name]
            return np.zeros(1)

        channels_of(spec, check)
        self._width = sum(len(p.values) for p in spec.predicates)
        self._plan: list[tuple[Any, ...]] = []  # per predicate, what its code needs, worked out once
        offset, sizes = 0, {}
        for p in spec.predicates:
            if isinstance(p, Pair):
                self._plan.append((p.name, offset, None, p.first, p.second, sizes[p.second]))
            elif isinstance(p, Bins):
                self._plan.append((p.name, offset, p.channel, p.edges, None, 0.0))
            else:
                self._plan.append((p.name, offset, p.channel, None, tests(p), (previous_scale(p), window(p))))
            sizes[p.name] = len(p.values)
            offset += len(p.values)
        self._looks_back = max((window(p) for p in spec.predicates), default=1)
        self._history: list[dict[str, float]] = []  # the last frames' channels, oldest first, at most _looks_back

    def reset(self) -> None:
        """The next frame starts an episode."""
        self._history = []

    def step(self, features: np.ndarray) -> np.ndarray:
        """The predicate values [columns] (bool) of the next frame, given its raw features [F]."""
        channels = {name: float(features[i]) for name, i in self._raw.items()}
        for derived in self.spec.channels:
            start = np.array([channels[c] for c in derived.start])
            end = np.array([channels[c] for c in derived.end])
            channels[derived.name] = float(distance(start, end, derived.decimals))
        history = self._history
        evidence = np.zeros(self._width, dtype=bool)
        found: dict[str, int] = {}
        for name, offset, channel, edges, rule, scale in self._plan:
            if channel is None:  # a pair: edges and rule hold its parts' names, scale the second's size
                value = pair_code(found[edges], found[rule], scale)
            elif rule is None:
                value = bisect.bisect_right(edges, channels[channel])
            else:  # scale: the previous value's factor and the window
                x, (factor, back) = channels[channel], scale
                before = history[max(len(history) - back, 0)][channel] if history else None
                value = code(rule, x, 0.0 if before is None else change(x, before, factor))
            found[name] = value
            evidence[offset + value] = True
        history.append(channels)
        if len(history) > self._looks_back:
            del history[0]
        return evidence
