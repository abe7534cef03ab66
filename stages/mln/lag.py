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
one step at a time for the backward. Both apply the same row-wise operations (stages/mln/lag_steps.py) in the
same order, so they give the same classes bit for bit (tests/stages/mln/test_lag.py checks this on DESK and Fetch
chains).
``decode_all`` decodes one chain with several decoders, sharing their forward passes and scores.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from mlnseq.catalog.decoders import Decoder, Decoding
from mlnseq.mln.chain_factors import ChainFactors
from mlnseq.mln.lag_steps import (MANY, decision_scores, legal_label, max_back, max_back_by_class, max_forward,
                                  probabilities_of, rows_of, scaled, sum_back, sum_back_by_class, sum_forward)

_FEW = 32  # transition matrices up to which a backward step moves each one's frames together
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
class _Tables:
    """A chain's factors in the form both passes use: per pairwise row its scaled and log matrices and allowed
    transitions, per frame its scaled and log unary."""

    link: np.ndarray
    transition: np.ndarray  # [P, C, C] exp(pairwise - row max), clipped
    log_transition: np.ndarray  # [P, C, C]
    allowed: np.ndarray  # [P, C, C] bool
    linear: np.ndarray  # [T, C]
    unary: np.ndarray  # [T, C]

    @classmethod
    def of(cls, factors: ChainFactors) -> _Tables:
        pairwise = factors.pairwise
        return cls(factors.link, scaled(pairwise, (-2, -1)), pairwise, allowed(pairwise), scaled(factors.unary),
                   factors.unary)

    def backward(self, semiring: str) -> tuple[Callable, Callable, np.ndarray, np.ndarray]:
        """A semiring's backward step (row-major, class-major), its transition matrices and its frame values."""
        if semiring == "sum":
            return sum_back, sum_back_by_class, self.transition, self.linear
        return max_back, max_back_by_class, self.log_transition, self.unary


def _positions(link: np.ndarray) -> list[tuple[np.ndarray | None, np.ndarray]]:
    """Per position within a chain, every chain side by side: which of the chains at the previous position reach it
    (None: all of them) and their frames at it."""
    first = np.flatnonzero(link < 0)
    length = np.diff(np.r_[first, len(link)])
    out, position, going = [], 0, None
    for stop in np.unique(length).tolist():  # the same chains go on from ``position`` up to ``stop``
        out += [(going if p == position else None, first + p) for p in range(position, stop)]
        going = length > stop
        first, length, position = first[going], length[going], stop
    return out


def _forward_pass(tables: _Tables, semiring: str, positions: list) -> tuple[np.ndarray, np.ndarray]:
    """The forward vectors [T, C] (alpha or delta) and the dead ends [T] of every chain, side by side."""
    n_frames, n_classes = tables.unary.shape
    out, dead = np.empty((n_frames, n_classes)), np.zeros(n_frames, dtype=bool)
    step, matrices, values = ((sum_forward, tables.transition, tables.linear) if semiring == "sum"
                              else (max_forward, tables.log_transition, tables.unary))
    last = None  # [chains, C] the last forward vector of each chain still going
    for going, frames in positions:
        if last is None:
            last, dead[frames] = step(None, None, values[frames])
        else:
            if going is not None:
                last = last[going]
            last, dead[frames] = step(last, matrices[tables.link[frames]], values[frames])
        out[frames] = last
    return out, dead


def _back(tables: _Tables, semiring: str, vectors: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """The backward vectors moved from ``frames`` into the frames before them. Where few transition matrices serve
    many frames, each matrix moves its frames at once (broadcast, not copied per frame: the same numbers)."""
    rows = tables.link[frames]
    back, _, matrices, frame_values = tables.backward(semiring)
    kinds = np.flatnonzero(np.bincount(rows, minlength=len(matrices))) if len(rows) >= MANY else rows
    if len(kinds) * MANY > len(rows) or len(kinds) > _FEW:
        return back(vectors, matrices[rows], frame_values[frames])
    if len(kinds) == 1:
        return back(vectors, matrices[kinds[0]][None], frame_values[frames])
    out = np.empty_like(vectors)
    for kind in kinds:
        mine = rows == kind
        out[mine] = back(vectors[mine], matrices[kind][None], frame_values[frames[mine]])
    return out


def _back_from(tables: _Tables, semiring: str, vectors: np.ndarray, values: np.ndarray, first: int,
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


def _backward_window(tables: _Tables, semiring: str, segment: np.ndarray, lag: int | None) -> np.ndarray:
    """[T, C] each frame's backward vector over its window: frames up to t + lag (None: to its chain's end)."""
    n_frames, n_classes = tables.unary.shape
    fill = 1.0 if semiring == "sum" else 0.0
    if lag is None:  # the whole chain: one backward pass, every chain side by side from its end
        vectors = np.full((n_frames, n_classes), fill)
        ends = np.r_[np.flatnonzero(np.diff(segment)), n_frames - 1]
        length = np.diff(np.r_[-1, ends])
        for p in range(1, int(length.max(initial=1))):
            frames = ends[length > p] - p + 1  # frame r moves into r - 1
            vectors[frames - 1] = _back(tables, semiring, vectors[frames], frames)
        return vectors
    # A window reaching past its chain's end or a dead end keeps its vector: what moves from a chain's first frame is
    # dropped, so that frame takes the previous frame's transition row and runs of one row stay unbroken.
    joined = np.where(tables.link >= 0, np.arange(n_frames), 0)
    carried = tables.link[np.maximum.accumulate(joined)]
    by_class = np.full((n_classes, n_frames), fill)  # class-major: see _back_from
    values = np.ascontiguousarray(tables.backward(semiring)[3].T)
    for step in range(min(lag, n_frames - 1), 0, -1):  # every frame t's window from t + step into t + step - 1
        kept = n_frames - step
        np.copyto(by_class[:, :kept], _back_from(tables, semiring, by_class[:, :kept], values, step, carried),
                  where=(segment[step:] == segment[:kept])[None, :])
    return np.ascontiguousarray(by_class.T)


def _legal_pass(tables: _Tables, scores: np.ndarray, semiring: str) -> np.ndarray:
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


@dataclass(frozen=True)
class LagDecoded:
    """Classes [T], decision scores turned into class probabilities [T, C], and the dead ends [R]."""

    path: np.ndarray
    probabilities: np.ndarray
    restarts: np.ndarray


def decode(factors: ChainFactors, decoding: Decoding) -> LagDecoded:
    """Decode whole recordings with a smooth, lagviterbi, posterior or filter decoder (or a legal form); frames whose
    chains end before t + lag are decided with what their chain holds (as ``lag_online.Online.finish``)."""
    return decode_all(factors, [decoding])[0]


def decode_all(factors: ChainFactors, decodings: Sequence[Decoding]) -> list[LagDecoded]:
    """``decode`` with each of ``decodings``, sharing what they have in common: the forward pass of each semiring,
    and the decision scores of each (semiring, lag), which a decoder and its legal form both read."""
    for decoding in decodings:
        if decoding.decoder in (Decoder.NONE, Decoder.VITERBI):
            raise ValueError(f"lag.decode runs the chain's marginal and lagged decoders, not {decoding.decoder.value}")
    if len(factors.link) == 0:
        empty = LagDecoded(np.zeros(0, dtype=np.int64), np.zeros((0, factors.n_classes)), np.zeros(0, dtype=np.int64))
        return [empty for _ in decodings]
    tables = _Tables.of(factors)
    positions = _positions(tables.link)
    forward: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    scored: dict[tuple[str, int | None], np.ndarray] = {}
    out = []
    for decoding in decodings:
        semiring = decoding.decoder.semiring
        if semiring not in forward:
            forward[semiring] = _forward_pass(tables, semiring, positions)
        vectors, dead = forward[semiring]
        lag = None if decoding.decoder.offline else decoding.lag
        if (semiring, lag) not in scored:
            segment = np.cumsum((tables.link < 0) | dead)
            backward = _backward_window(tables, semiring, segment, lag) if lag != 0 else \
                np.full_like(vectors, 1.0 if semiring == "sum" else 0.0)
            scored[semiring, lag] = decision_scores(semiring, vectors, backward)
        scores = scored[semiring, lag]
        path = _legal_pass(tables, scores, semiring) if decoding.decoder.legal else scores.argmax(axis=1)
        out.append(LagDecoded(path, probabilities_of(scores, semiring), np.flatnonzero(dead)))
    return out
