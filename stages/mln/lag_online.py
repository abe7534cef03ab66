"""Lagged decoding one frame at a time: ``Online`` holds at most lag + 1 frames and decides frame t once t + lag
has arrived, with the row-wise steps of stages/mln/lag_steps.py, so that it gives the same classes as ``lag.decode``
over the whole recording. Frames held back to be decided together (``step(..., decide=False)``, an episode's end)
have their windows computed side by side by ``lag.backward_vectors``: the same numbers, a step per frame of the lag
for all of them."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from itertools import islice

import numpy as np

from mlnseq.catalog.decoders import Decoder, Decoding
from mlnseq.mln.lag import Tables, allowed, backward_vectors
from mlnseq.mln.lag_steps import decision_scores, legal_label, max_forward, probabilities_of, scaled, sum_forward


_sum, _max, _times, _plus, _minus, _over = (np.add.reduce, np.maximum.reduce, np.multiply, np.add, np.subtract,
                                            np.true_divide)  # the ufuncs themselves: no method call per step
_TOGETHER = 4  # frames to decide from which their windows go side by side


def _window(semiring: str, n_classes: int, later: list) -> np.ndarray:
    """[C] the backward vector of one frame over the frames held after it: the backward steps of
    stages/mln/lag_steps.py on one row, the same numbers with fewer numpy calls (each row's sum runs over the same
    axis in the same order)."""
    if semiring == "sum":
        vector = np.ones(n_classes)
        for frame in reversed(later):  # (..., transition, log_transition, allowed, linear, unary, ...)
            moved = _sum(_times(frame[3], _times(frame[6], vector)), axis=1)
            top = _max(moved)
            vector = _over(moved, top) if top > 0 else np.ones(n_classes)
        return vector
    vector = np.zeros(n_classes)
    for frame in reversed(later):
        moved = _max(_plus(frame[4], _plus(frame[7], vector)), axis=1)
        top = _max(moved)
        vector = _minus(moved, top) if np.isfinite(top) else np.zeros(n_classes)
    return vector


@dataclass(frozen=True)
class Final:
    """A frame decided: its index in the stream (frames counted from the first step), class and probabilities."""

    index: int
    label: int
    probabilities: np.ndarray
    restarted: bool  # a dead end: no class possible given the previous frames, the chain started anew there


class Online:
    """A lagged decoder one frame at a time: ``step`` takes a frame's unary [C] and the pairwise matrix [C, C]
    joining it to the previous frame (None: it starts a chain) and returns the frames decided by it (frame t once
    t + lag has arrived); ``finish`` decides the pending frames at once (an episode's end). Offline decoders
    (posterior) keep the whole episode and decide it at ``finish``. Holds at most lag + 1 frames otherwise, and
    the frames ``step(..., decide=False)`` held back until ``decide``."""

    def __init__(self, n_classes: int, decoding: Decoding):
        if decoding.decoder in (Decoder.NONE, Decoder.VITERBI):
            raise ValueError(f"no online form of {decoding.decoder.value} here")
        self.n_classes, self.decoding = n_classes, decoding
        self.semiring = decoding.decoder.semiring
        self.lag = None if decoding.decoder.offline else decoding.lag
        self._frames: deque = deque()  # (index, forward, segment, transition, log_transition, allowed, linear, unary,
        #                                starts, dead): the rows of this frame, the matrices joining it to the previous
        #                                (the same objects over a run of one pairwise matrix)
        self._index = 0
        self._segment = 0
        self._previous: np.ndarray | None = None  # the last forward vector (None: the next frame starts a chain)
        self._emitted: int | None = None  # the class emitted last within the chain (None: none yet)
        self._matrix = (b"", None)  # the last pairwise matrix's bytes and its forms
        self._dead = False

    @property
    def current(self) -> np.ndarray:
        """The last frame's class probabilities given the frames so far (its filtered belief; max: normalised)."""
        return probabilities_of(self._previous, self.semiring)[0]

    @property
    def restarted(self) -> bool:
        """Whether the last frame was a dead end (the chain started anew there)."""
        return self._dead

    @property
    def pending(self) -> int:
        """Frames received but not decided yet."""
        return len(self._frames)

    def _forms(self, pairwise: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """[C, C] the pairwise matrix scaled, as logs, and its allowed transitions, made once per run of it."""
        key = pairwise.tobytes()
        if key != self._matrix[0]:  # a stream passes the same few matrices again and again
            self._matrix = (key, (scaled(pairwise, (-2, -1)), pairwise, allowed(pairwise)))
        return self._matrix[1]

    def step(self, unary: np.ndarray, pairwise: np.ndarray | None, decide: bool = True) -> list[Final]:
        """Take a frame; return the frames it lets decide (``decide=False``: none yet, ``decide`` does later)."""
        unary = np.asarray(unary, dtype=np.float64)[None]
        linear = scaled(unary)
        starts = pairwise is None or self._previous is None  # the window never reads a chain start's matrices
        if starts:
            self._previous = None
            self._segment += 1
            transition = log_transition = allowed_ = None
        else:
            transition, log_transition, allowed_ = self._forms(np.asarray(pairwise, dtype=np.float64))
        if self.semiring == "sum":
            forward, dead = sum_forward(self._previous, None if starts else transition[None], linear)
        else:
            forward, dead = max_forward(self._previous, None if starts else log_transition[None], unary)
        if dead[0]:
            self._segment += 1
        self._previous, self._dead = forward, bool(dead[0])
        self._frames.append((self._index, forward, self._segment, transition, log_transition, allowed_, linear[0],
                             unary[0], starts, bool(dead[0])))
        self._index += 1
        return self.decide() if decide else []

    def decide(self) -> list[Final]:
        """Decide every held frame that has ``lag`` frames after it (offline decoders: none before ``finish``)."""
        if self.lag is None or len(self._frames) <= self.lag:
            return []
        return self._decide_oldest(len(self._frames) - self.lag)

    def finish(self) -> list[Final]:
        """Decide every pending frame (the episode or the input ended); the next step starts a new chain."""
        out = self._decide_oldest(len(self._frames))
        self._previous, self._emitted = None, None
        return out

    def _decide_oldest(self, count: int) -> list[Final]:
        """Decide the ``count`` oldest held frames: one by one where they are few, else their windows side by side."""
        if count < _TOGETHER or all(frame[8] for frame in self._frames):  # (all chain starts: no matrix to stack)
            return [self._decide() for _ in range(count)]
        frames = list(self._frames)
        tables, segment = self._tables(frames)
        window = dict(backward_vectors(tables, self.semiring, segment, {self.lag}))[self.lag][:count]
        scores = decision_scores(self.semiring, np.concatenate([frame[1] for frame in frames[:count]]), window)
        probabilities, labels = probabilities_of(scores, self.semiring), scores.argmax(axis=1).tolist()
        return [self._final(frame, scores[i], labels[i], probabilities[i]) for i, frame in enumerate(frames[:count])]

    def _tables(self, frames: list) -> tuple[Tables, np.ndarray]:
        """The held frames as ``lag.Tables`` (a transition row per run of the same matrix) and their segments."""
        link, runs = [], []  # runs: the first frame of each run of one matrix
        for frame in frames:
            if not frame[8] and (not runs or frame[3] is not runs[-1][3]):
                runs.append(frame)
            link.append(-1 if frame[8] else len(runs) - 1)
        transition, log_transition, allowed_ = (np.array([run[k] for run in runs]) for k in (3, 4, 5))
        return (Tables(np.array(link), transition, log_transition, allowed_, np.array([frame[6] for frame in frames]),
                       np.array([frame[7] for frame in frames])), np.array([frame[2] for frame in frames]))

    def _decide(self) -> Final:
        """Decide the oldest pending frame from the frames of its chain held after it."""
        forward, segment = self._frames[0][1:3]
        reach = None if self.lag is None else self.lag + 1
        later = [f for f in islice(self._frames, 1, reach) if f[2] == segment]
        scores = decision_scores(self.semiring, forward, _window(self.semiring, self.n_classes, later)[None])
        return self._final(self._frames[0], scores[0], int(scores[0].argmax()),
                           probabilities_of(scores, self.semiring)[0])

    def _final(self, frame: tuple, scores: np.ndarray, label: int, probabilities: np.ndarray) -> Final:
        """The oldest held frame decided: its free argmax ``label``, or the legal choice after the last one emitted."""
        index, *_, starts, dead = frame
        if self.decoding.decoder.legal and not starts and self._emitted is not None:
            label = legal_label(scores.tolist(), frame[5][self._emitted].tolist(), self.semiring, label)
        self._frames.popleft()
        self._emitted = label
        return Final(index, label, probabilities, dead)
