"""Decoding a chain with a lag: fixed-lag smoothing, fixed-lag Viterbi, full posterior marginals, and the legal
forms that never emit a transition the chain forbids (stages/catalog/decoders.py names them).

Scores of frame t with lag L, over the frames of t's chain up to s = min(t + L, its last frame):
  sum (smooth, posterior):  p(y_t | frames to s)  = alpha_t * beta_t^(s), beta from s back to t
  max (lagviterbi):         the best score of a path to s through y_t = delta_t + psi_t^(s) (max-product)
and the decision is their argmax (ties: the lower class); a legal form takes the argmax among the classes the
transition factor allows after the class it emitted last (allowed: finite and at most FORBID nats below the
row's best; none of them possible given the frames: the first allowed class; none allowed at all: the free
argmax). Dead ends (no class possible given the previous frames)
restart the chain there, as ``chain.Filter`` does; the windows do not reach across a chain start.

``lag_online.Online`` runs one frame at a time with a buffer of L + 1 frames (O(L C^2) per frame); ``decode`` runs whole
recordings, every chain side by side one position at a time for the forward pass, every window side by side
one step at a time for the backward (the windows of every lag grow together: one step per frame of the largest).
Both apply the same row-wise operations (stages/mln/lag_steps.py) in the same order, so they give the same classes
bit for bit (tests/stages/mln/test_lag.py checks this on DESK and Fetch chains).
``decode_all`` decodes one chain with several decoders, sharing their forward passes and scores.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from mlnseq.catalog.decoders import Decoder, Decoding
from mlnseq.mln.chain import Decoded
from mlnseq.mln.chain_factors import ChainFactors
from mlnseq.mln.lag_steps import (MANY, decision_scores, legal_label, max_back, max_back_by_class, max_forward,
                                  probabilities_of, rows_of, scaled, sum_back, sum_back_by_class, sum_forward)

_ROWS = 4096  # frames a pass gathers at once (offsets times chains)
_BLOCK = 8192  # frames whose lagged windows are computed together (elementwise: any split gives the same numbers)
FORBID = 30.0  # nats below its row's best at which a transition counts as forbidden (e^-30: effectively 0)


def allowed(pairwise: np.ndarray) -> np.ndarray:
    """bool [..., C, C]: transitions (class at t-1, class at t) the factor allows: finite, within FORBID of the best
    transition from that class."""
    pairwise = np.asarray(pairwise, dtype=np.float64)
    top = pairwise.max(axis=-1, keepdims=True)
    with np.errstate(invalid="ignore"):
        return np.isfinite(pairwise) & (pairwise - np.where(np.isfinite(top), top, 0.0) > -FORBID)


def forbidden_transitions(factors: ChainFactors, path: np.ndarray) -> int:
    """How many frames of ``path`` follow their previous frame by a transition the chain forbids."""
    path = np.asarray(path, dtype=np.int64)
    joined = np.flatnonzero(factors.link >= 0)
    if not len(joined):
        return 0
    ok = allowed(factors.pairwise)[factors.link[joined], path[joined - 1], path[joined]]
    return int((~ok).sum())


def with_start(factors: ChainFactors, start: np.ndarray | None) -> ChainFactors:
    """The factors with a start distribution's log-probabilities [C] added at every chain's first frame."""
    if start is None:
        return factors
    unary = factors.unary.copy()
    unary[factors.link < 0] += np.asarray(start, dtype=np.float64)
    return ChainFactors(unary, factors.pairwise, factors.link)


def fit_start(labels: np.ndarray, starts: np.ndarray, n_classes: int, smoothing: float = 1.0) -> np.ndarray:
    """log p(class of a chain's first frame) [C]: the classes chains begin with, counted with ``smoothing`` added
    to every class (Laplace)."""
    counts = np.bincount(np.asarray(labels)[np.asarray(starts, dtype=bool)], minlength=n_classes)[:n_classes]
    counts = counts + smoothing
    return np.log(counts / counts.sum())


# --- whole recordings -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Tables:
    """A chain's factors in the form both passes use: per pairwise row its scaled and log matrices and allowed
    transitions, per frame its scaled and log unary."""

    link: np.ndarray
    transition: np.ndarray  # [P, C, C] exp(pairwise - row max), clipped
    log_transition: np.ndarray  # [P, C, C]
    allowed: np.ndarray  # [P, C, C] bool
    linear: np.ndarray  # [T, C]
    unary: np.ndarray  # [T, C]

    @classmethod
    def of(cls, factors: ChainFactors) -> Tables:
        pairwise = factors.pairwise
        return cls(factors.link, scaled(pairwise, (-2, -1)), pairwise, allowed(pairwise), scaled(factors.unary),
                   factors.unary)

    def backward(self, semiring: str) -> tuple[Callable, Callable, np.ndarray, np.ndarray]:
        """A semiring's backward step (row-major, class-major), its transition matrices and its frame values."""
        if semiring == "sum":
            return sum_back, sum_back_by_class, self.transition, self.linear
        return max_back, max_back_by_class, self.log_transition, self.unary


def _runs(anchors: np.ndarray, lengths: np.ndarray, sign: int) -> list[tuple[np.ndarray | None, np.ndarray]]:
    """Offsets 0, 1, ... within every chain side by side (frame ``anchor + sign * offset``), in blocks of offsets
    over which the same chains go on: which of the previous block's chains reach the block (None: all of them), and
    their frames [offsets, chains]."""
    out, position, going = [], 0, None
    for stop in np.unique(lengths).tolist():  # the same chains go on from ``position`` up to ``stop``
        size = max(1, _ROWS // len(anchors))
        for start in range(position, stop, size):
            offsets = np.arange(start, min(start + size, stop))
            out.append((going if start == position else None, anchors[None, :] + sign * offsets[:, None]))
        going = lengths > stop
        anchors, lengths, position = anchors[going], lengths[going], stop
    return out


def _forward_pass(tables: Tables, semiring: str, runs: list) -> tuple[np.ndarray, np.ndarray]:
    """The forward vectors [T, C] (alpha or delta) and the dead ends [T] of every chain, side by side (``runs``:
    ``_runs`` from the chains' first frames)."""
    out, dead = np.empty(tables.unary.shape), np.zeros(len(tables.link), dtype=bool)
    step, matrices, values = ((sum_forward, tables.transition, tables.linear) if semiring == "sum"
                              else (max_forward, tables.log_transition, tables.unary))
    last = None  # [chains, C] the last forward vector of each chain still going
    for going, frames in runs:
        if going is not None:
            last = last[going]
        moving, frame_values = matrices[tables.link[frames]], values[frames]  # gathered once for the block
        block, block_dead = np.empty(frame_values.shape), np.zeros(frames.shape, dtype=bool)
        for i in range(len(frames)):
            last, block_dead[i] = step(last, None if last is None else moving[i], frame_values[i])
            block[i] = last
        out[frames], dead[frames] = block, block_dead
    return out, dead


def _back_from(tables: Tables, semiring: str, vectors: np.ndarray, values: np.ndarray, first: int,
               link: np.ndarray) -> np.ndarray:
    """The class-major backward vectors [C, N] moved from the frames ``first``, ``first`` + 1, ... into the frames
    before them, by the transition rows ``link`` [T] and the frames' class-major ``values`` [C, T] (linear or
    unary); each run of frames sharing a transition matrix moves at once where the runs are long."""
    n = vectors.shape[1]
    rows = link[first:first + n]
    cuts = np.flatnonzero(rows[1:] != rows[:-1]) + 1
    back, back_by_class, matrices, _ = tables.backward(semiring)
    if (len(cuts) + 1) * MANY > n:  # many short runs: frame by frame, each with its matrix
        moving, frame_values = rows_of(vectors, values[:, first:first + n])
        return back(moving, matrices[rows], frame_values).T
    out = np.empty_like(vectors)
    for start, stop in zip(np.r_[0, cuts], np.r_[cuts, n]):
        out[:, start:stop] = back_by_class(vectors[:, start:stop], matrices[rows[start]],
                                           values[:, first + start:first + stop])
    return out


def _whole_chains(tables: Tables, semiring: str, segment: np.ndarray) -> np.ndarray:
    """[T, C] each frame's backward vector over the rest of its chain: one backward pass, every chain side by side
    from its end (the windows stop at dead ends, as ``segment`` numbers them)."""
    n_frames = len(segment)
    back, _, matrices, frame_values = tables.backward(semiring)
    vectors = np.full(tables.unary.shape, 1.0 if semiring == "sum" else 0.0)
    ends = np.r_[np.flatnonzero(np.diff(segment)), n_frames - 1]
    moving = None  # [chains, C] the backward vector of each chain still going
    for going, frames in _runs(ends, np.diff(np.r_[-1, ends]), -1):
        if going is not None:
            moving = moving[going]
        later = np.minimum(frames + 1, n_frames - 1)  # the frame that moves into each frame
        transitions, values = matrices[tables.link[later]], frame_values[later]  # gathered once for the block
        block = np.empty((*frames.shape, vectors.shape[1]))
        for i in range(len(frames)):
            moving = vectors[frames[i]] if moving is None else back(moving, transitions[i], values[i])
            block[i] = moving
        vectors[frames] = block
    return vectors


def _windows(tables: Tables, semiring: str, segment: np.ndarray, lags: Sequence[int]) -> dict[int, np.ndarray]:
    """Per lag in ``lags`` (> 0), [T, C] each frame's backward vector over its window, the frames up to t + lag.
    The window of t with lag L is that of t + 1 with lag L - 1 moved into t, so one step per lag up to the largest
    serves every lag; blocks of frames (with the largest lag's frames after them) go one at a time, their arrays
    in the cache. A window reaching past its chain's end or a dead end stops there."""
    n_frames, n_classes = tables.unary.shape
    fill = 1.0 if semiring == "sum" else 0.0
    # What moves from a chain's first frame is dropped, so that frame takes the previous frame's transition row and
    # runs of one row stay unbroken.
    joined = np.where(tables.link >= 0, np.arange(n_frames), 0)
    carried = tables.link[np.maximum.accumulate(joined)]
    values = np.ascontiguousarray(tables.backward(semiring)[3].T)
    going_on = (segment[1:] == segment[:-1])[None, :]  # frame t + 1 is in t's window
    out = {lag: np.empty((n_frames, n_classes)) for lag in lags}
    largest = max(lags, default=0)
    for first in range(0, n_frames, _BLOCK):
        stop, reach = min(first + _BLOCK, n_frames), min(first + _BLOCK + largest, n_frames)
        window = np.full((n_classes, reach - first), fill)  # class-major (see _back_from): lag 0
        for lag in range(1, largest + 1):
            moved = np.full_like(window, fill)
            np.copyto(moved[:, :-1], _back_from(tables, semiring, window[:, 1:], values, first + 1, carried),
                      where=going_on[:, first:reach - 1])
            window = moved
            if lag in out:
                out[lag][first:stop] = window[:, :stop - first].T
    return out


def backward_vectors(tables: Tables, semiring: str, segment: np.ndarray,
                     lags: set[int | None]) -> Iterator[tuple[int | None, np.ndarray]]:
    """(lag, [T, C]) each frame's backward vector for each of ``lags``: 0 (none), a window, None (the whole chain)."""
    yield from _windows(tables, semiring, segment, [lag for lag in lags if lag]).items()
    if 0 in lags:
        yield 0, np.full(tables.unary.shape, 1.0 if semiring == "sum" else 0.0)
    if None in lags:
        yield None, _whole_chains(tables, semiring, segment)


def _legal_pass(tables: Tables, scores: np.ndarray, semiring: str) -> np.ndarray:
    """Each frame's argmax among the classes allowed after the previous frame's choice (a chain's first frame: the
    free argmax). The free argmax stands wherever it is possible and allowed after the previous choice; only the
    other frames run ``legal_label``, one at a time."""
    link = tables.link
    free = scores.argmax(axis=1)
    floor = 0.0 if semiring == "sum" else -np.inf
    possible = scores[np.arange(len(scores)), free] > floor
    joined = link >= 0
    previous = np.r_[0, free[:-1]]
    agrees = ~joined | (possible & tables.allowed[np.where(joined, link, 0), previous, free])
    path, n_frames = free.copy(), len(free)
    disagreeing = np.flatnonzero(~agrees)  # frames where following the free argmax breaks a rule
    k = 0
    while k < len(disagreeing):
        t = int(disagreeing[k])
        while t < n_frames and joined[t]:  # off the free path: decide frame by frame until it is rejoined
            path[t] = legal_label(scores[t].tolist(), tables.allowed[link[t], path[t - 1]].tolist(), semiring,
                                  int(free[t]))
            if path[t] == free[t]:  # back on the free path: the next frame follows ``agrees``
                break
            t += 1
        k = int(np.searchsorted(disagreeing, t + 1))
    return path


def decode(factors: ChainFactors, decoding: Decoding) -> Decoded:
    """Decode whole recordings with a smooth, lagviterbi, posterior or filter decoder (or a legal form); frames whose
    chains end before t + lag are decided with what their chain holds (as ``lag_online.Online.finish``)."""
    return decode_all(factors, [decoding])[0]


def decode_all(factors: ChainFactors, decodings: Sequence[Decoding]) -> list[Decoded]:
    """``decode`` with each of ``decodings``, sharing what they have in common: the forward pass of each semiring,
    and the decision scores of each (semiring, lag), which a decoder and its legal form both read. Each result: the
    decision scores turned into class probabilities [T, C], the classes [T] and the dead ends [R]."""
    for decoding in decodings:
        if decoding.decoder in (Decoder.NONE, Decoder.VITERBI):
            raise ValueError(f"lag.decode runs the chain's marginal and lagged decoders, not {decoding.decoder.value}")
    if len(factors.link) == 0:
        return [Decoded.empty(factors.n_classes) for _ in decodings]
    tables = Tables.of(factors)
    first = np.flatnonzero(tables.link < 0)
    runs = _runs(first, np.diff(np.r_[first, len(tables.link)]), 1)
    wanted = [(d.decoder.semiring, None if d.decoder.offline else d.lag) for d in decodings]
    scored: dict[tuple[str, int | None], tuple[np.ndarray, np.ndarray]] = {}  # scores, probabilities
    restarts: dict[str, np.ndarray] = {}
    for semiring in dict.fromkeys(semiring for semiring, _ in wanted):
        vectors, dead = _forward_pass(tables, semiring, runs)
        restarts[semiring] = np.flatnonzero(dead)
        segment = np.cumsum((tables.link < 0) | dead)
        for lag, window in backward_vectors(tables, semiring, segment, {lag for s, lag in wanted if s == semiring}):
            scores = decision_scores(semiring, vectors, window)
            scored[semiring, lag] = scores, probabilities_of(scores, semiring)
    out = []
    for decoding, key in zip(decodings, wanted):
        scores, probabilities = scored[key]
        path = _legal_pass(tables, scores, key[0]) if decoding.decoder.legal else scores.argmax(axis=1)
        out.append(Decoded(probabilities, path, restarts[key[0]]))
    return out
