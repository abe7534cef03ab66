"""A chain's messages in log space, frame by frame: what explaining a decision reads.

A decoder decides frame t by scores over its classes; in log space each is a sum of three parts, up to a
constant per frame that no comparison of two classes sees:

  score_t(y) = unary_t(y) + past_t(y) + future_t(y)

- ``past``: what the frames before carry in. Sum-product (filter, smoothing, posterior): log sum_y' alpha_{t-1}(y')
  exp(pairwise_t(y', y)), alpha_{t-1} the normalised forward vector; max-product (lagged Viterbi, Viterbi):
  max_y' delta_{t-1}(y') + pairwise_t(y', y). 0 at a chain's first frame and at a dead end (no class possible given
  the frames before: the chain restarts there from the frame's unary, as every decoder does).
- ``future``: what the frames after carry back, over the decoder's window: none (filter), the frames up to t + lag
  (smoothing, lagged Viterbi), or the rest of the chain (posterior, Viterbi); windows stop at dead ends.
- ``unary``: the frame's own log-potentials (a frame where no class is possible from them alone counts as
  uniform, as the decoders count it).

The decoders (stages/mln/chain.py, lag.py) compute the same quantities in linear space, scaled, with entries more
than ``CLIP`` (300) nats below their row's best counted as 300 below; these are computed anew, exactly, so that a
decision's margin splits into its parts. Nothing here changes a decoder's numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mlnseq.mln.chain_factors import ChainFactors

SUM, MAX = "sum", "max"


def combine(values: np.ndarray, axis: int, semiring: str) -> np.ndarray:
    """log-sum-exp (sum) or max (max) over ``axis``; -inf where every entry is -inf."""
    if semiring == MAX:
        return values.max(axis=axis)
    top = values.max(axis=axis, keepdims=True)
    safe = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(np.log(np.exp(values - safe).sum(axis=axis, keepdims=True)) + safe, axis=axis)


def less_top(values: np.ndarray, semiring: str) -> np.ndarray:
    """Rows less their log-sum-exp (sum: log-probabilities) or their max (max); a row of -inf as it is."""
    if values.ndim == 1 and np.isfinite(values).all():  # a forward vector with every class possible
        top = values.max()
        return values - top if semiring == MAX else values - (np.log(np.exp(values - top).sum()) + top)
    top = combine(values, -1, semiring)[..., None]
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(top), values - np.where(np.isfinite(top), top, 0.0), values)


@dataclass(frozen=True)
class Messages:
    """Every frame's decision parts [T, C] for one semiring and window, and where the chain restarted."""

    semiring: str
    unary: np.ndarray
    past: np.ndarray
    future: np.ndarray
    before: np.ndarray  # [T, C] the previous frame's log forward vector (normalised) that ``past`` is made from
    joined: np.ndarray  # [T] bool: the frame's past counts (neither a chain's first frame nor a dead end)
    restarted: np.ndarray  # [T] bool: a dead end, or a frame no class is possible at from its unary alone
    reach: np.ndarray  # [T] int64: the last frame the decision of frame t reads
    scores: np.ndarray = field(init=False)  # [T, C] each frame's decision scores, up to a constant per frame

    def __post_init__(self) -> None:
        object.__setattr__(self, "scores", self.unary + self.past + self.future)


def messages(factors: ChainFactors, semiring: str, lag: int | None) -> Messages:
    """The decision parts of every frame: the past in ``semiring``, the future over ``lag`` frames (None: the rest
    of the chain; 0: none)."""
    unary, past, before, joined, restarted = _forward(factors, semiring)
    cut = (factors.link < 0) | restarted  # where a window stops: a frame after it that starts anew
    if lag == 0:
        future = np.zeros_like(unary)
    elif lag is None:
        future = _rest_of_chain(factors, unary, cut, semiring)
    else:
        future = _window(factors, unary, cut, semiring, lag)
    starts = np.flatnonzero(cut)
    last = np.r_[starts[1:] - 1, len(cut) - 1][np.cumsum(cut) - 1]  # each frame's segment's last frame
    reach = last if lag is None else np.minimum(np.arange(len(cut)) + lag, last)
    return Messages(semiring, unary, past, future, before, joined, restarted, reach.astype(np.int64))


def _forward(factors: ChainFactors, semiring: str):
    """Frame by frame: the unary as decoded, the past, the forward vector it came from, and the dead ends."""
    n_frames, n_classes = factors.unary.shape
    unary, past = factors.unary.copy(), np.zeros((n_frames, n_classes))
    before = np.full((n_frames, n_classes), np.nan)
    joined, restarted = np.zeros(n_frames, dtype=bool), np.zeros(n_frames, dtype=bool)
    link, pairwise = factors.link.tolist(), factors.pairwise
    last = None  # the previous frame's normalised forward vector
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for t in range(n_frames):
            total = unary[t]
            if link[t] >= 0 and last is not None:
                came = carried_in(last, pairwise[link[t]], semiring)
                moved = total + came
                if moved.max() > -np.inf:
                    past[t], before[t], joined[t], total = came, last, True, moved
                else:
                    restarted[t] = True
            if not total.max() > -np.inf:  # no class possible from the unary alone: uniform
                unary[t], total, restarted[t] = 0.0, np.zeros(n_classes), True
            last = less_top(total, semiring)
    return unary, past, before, joined, restarted


def carried_in(last: np.ndarray, transition: np.ndarray, semiring: str) -> np.ndarray:
    """[C] what a forward vector [C] carries into the next frame through ``transition`` [C, C]."""
    moved = last[:, None] + transition
    top = moved.max(axis=0)
    if semiring == MAX:
        return top
    if np.isfinite(top).all():
        return np.log(np.exp(moved - top).sum(axis=0)) + top
    return combine(moved, 0, semiring)


def moved_back(pairwise: np.ndarray, values: np.ndarray, semiring: str) -> np.ndarray:
    """[N, C]: combine over the next class of pairwise [N, C, C] + values [N, 1, C], less each row's top."""
    return less_top(combine(pairwise + values[:, None, :], 2, semiring), semiring)


def _rest_of_chain(factors: ChainFactors, unary: np.ndarray, cut: np.ndarray, semiring: str) -> np.ndarray:
    """[T, C] each frame's backward vector over the rest of its chain (up to a dead end)."""
    n_frames = len(unary)
    future = np.zeros_like(unary)
    for t in range(n_frames - 2, -1, -1):
        if not cut[t + 1]:
            future[t] = moved_back(factors.pairwise[factors.link[t + 1]][None], (unary[t + 1] + future[t + 1])[None],
                                    semiring)[0]
    return future


def _window(factors: ChainFactors, unary: np.ndarray, cut: np.ndarray, semiring: str, lag: int) -> np.ndarray:
    """[T, C] each frame's backward vector over the frames up to t + lag (up to a dead end): the window of t with
    lag L is that of t + 1 with lag L - 1 moved into t, every frame side by side."""
    window = np.zeros_like(unary)
    going_on = np.flatnonzero(~cut[1:])  # frames t whose next frame t + 1 is in their window
    pairwise = factors.pairwise[factors.link[going_on + 1]]
    for _ in range(lag):
        moved = np.zeros_like(window)
        moved[going_on] = moved_back(pairwise, unary[going_on + 1] + window[going_on + 1], semiring)
        window = moved
    return window
