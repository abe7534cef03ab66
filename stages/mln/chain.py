"""Exact inference on linear chains of frames: forward filtering, forward-backward, Viterbi, log Z.

A chain's distribution is p(y) = exp(sum_t unary[t, y_t] + sum_t pairwise[link[t], y_{t-1}, y_t]) / Z,
every frame with ``link[t] == -1`` starting a new chain (an episode's, or a block's, first frame).
All chains of a call are one long product of per-step matrices: a chain start is the matrix whose rows
all equal exp(unary[t]), so each chain's total is carried into the next and log Z is their sum.

Dead ends (a frame where no class is possible given the previous frames: hard rules contradict each
other or the previous state) restart the chain at that frame from its unary alone, without the
forbidding transition; a frame whose unary is -inf everywhere becomes uniform. ``Filter`` does this one
frame at a time; the batch functions find the same frames and then treat them as chain starts, so they
agree (``decode`` also says which frames they were). Where the scan's block products underflow although
every frame stays possible (a chain the hard rules hold in a few states for hundreds of frames, their
probabilities far below e^-745 within a block), the forward pass runs frame by frame instead, as ``Filter``.
Numbers: each unary row and each pairwise matrix is scaled by its maximum and finite entries
more than ``CLIP`` below it count as ``CLIP`` below (e^-300: far below any probability that matters),
so a product of one step never underflows to zero while a class is possible.

Long chains are not a Python loop per frame but a parallel scan over a binary tree of the steps, one
numpy call per tree level (about 2 log2 T calls in all): going up, each node holds the product of its
steps' matrices (scaled by its total); going down, each node receives the forward vector entering it
(the left child its parent's, the right child that vector moved through its left sibling) and the
backward vector leaving it (mirrored). Viterbi is the same scan in the (max, +) semiring, and its
backtracking a scan over the composition of the back-pointer maps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CLIP = 300.0


@dataclass(frozen=True)
class ChainFactors:
    unary: np.ndarray  # [T, C] float64 log-potentials of each frame's class; -inf: impossible
    pairwise: np.ndarray  # [P, C, C] float64 log-potentials of (class at t-1, class at t); -inf forbids
    link: np.ndarray  # [T] int64: the row of `pairwise` joining frame t-1 to frame t; -1 where frame t starts a chain

    def __post_init__(self) -> None:
        unary, pairwise, link = (np.asarray(self.unary, dtype=np.float64), np.asarray(self.pairwise, dtype=np.float64),
                                 np.asarray(self.link, dtype=np.int64))
        object.__setattr__(self, "unary", unary)
        object.__setattr__(self, "pairwise", pairwise)
        object.__setattr__(self, "link", link)
        if unary.ndim != 2 or pairwise.ndim != 3 or pairwise.shape[1:] != (unary.shape[1],) * 2 \
                or link.shape != (len(unary),):
            raise ValueError(f"chain factors of mismatched shapes: unary {unary.shape}, pairwise {pairwise.shape}, "
                             f"link {link.shape}")
        if len(link) and (link[0] != -1 or link.min() < -1 or link.max() >= len(pairwise)):
            raise ValueError("link must be -1 at frame 0 and index a row of pairwise (or be -1) elsewhere")
        for name, values in (("unary", unary), ("pairwise", pairwise)):
            if not (values < np.inf).all():  # NaN and +inf fail the comparison
                raise ValueError(f"{name} log-potentials must be finite or -inf")

    @property
    def n_classes(self) -> int:
        return self.unary.shape[1]


def _scaled(values: np.ndarray, axes: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """exp(values - max) over ``axes`` with finite entries clipped at -CLIP, and the max (-inf: all -inf)."""
    top = values.max(axis=axes, keepdims=True)
    if (values > -np.inf).all():
        return np.exp(np.maximum(values - top, -CLIP)), np.squeeze(top, axis=axes)
    finite_top = np.where(np.isfinite(top), top, 0.0)
    linear = np.exp(np.clip(values - finite_top, -CLIP, 0.0)) * np.isfinite(values)
    return linear, np.squeeze(top, axis=axes)


class Filter:
    """The online filter, one frame at a time (for live streams): the same numbers as ``filtered``."""

    def __init__(self, n_classes: int):
        self.n_classes = n_classes
        self._alpha: np.ndarray | None = None
        self.restarted = False
        self._pairwise = b""  # the last pairwise matrix passed (its bytes), and its scaled form
        self._transition = np.ones((n_classes, n_classes))

    def reset(self) -> None:
        """The next frame starts a new chain."""
        self._alpha = None

    def step(self, unary: np.ndarray, pairwise: np.ndarray | None) -> np.ndarray:
        """log p(y_t | frames so far) [C]; pairwise [C, C] joins the previous frame (None: first frame).
        ``restarted`` then says whether the frame was a dead end (no class possible: the chain starts anew)."""
        self.restarted = self._advance(unary, pairwise)
        if self._alpha.min() > 0.0:
            return np.log(self._alpha)
        with np.errstate(divide="ignore"):
            return np.log(self._alpha)

    def _advance(self, unary: np.ndarray, pairwise: np.ndarray | None) -> bool:
        """Advance by one frame; whether it was a dead end (no class possible: restarted)."""
        unary = np.asarray(unary, dtype=np.float64)
        top = unary.max()
        if top == -np.inf:
            linear = np.zeros(self.n_classes)
        else:
            shifted = unary - top
            linear = np.exp(shifted) if shifted.min() >= -CLIP else _scaled(unary, (0,))[0]
        total = 0.0
        joined = self._alpha is not None and pairwise is not None
        if joined:
            pairwise = np.asarray(pairwise, dtype=np.float64)
            key = pairwise.tobytes()
            if key != self._pairwise:  # a stream passes the same few matrices again and again
                self._transition, self._pairwise = _scaled(pairwise, (0, 1))[0], key
            alpha = (self._alpha @ self._transition) * linear
            total = alpha.sum()
        dead = total == 0.0 and (joined or top == -np.inf)
        if total == 0.0:  # a chain start, or a dead end: restart from the unary alone (uniform if all -inf)
            alpha = linear if top > -np.inf else np.ones(self.n_classes)
            total = alpha.sum()
        self._alpha = alpha / total
        return bool(dead)


def _restarted(factors: ChainFactors) -> ChainFactors:
    """The factors with chain starts where ``Filter`` meets a dead end, and uniform unaries where all were
    -inf (a plain loop over the frames: only run when the fast pass met a dead end)."""
    chain = Filter(factors.n_classes)
    dead = np.array([chain._advance(row, None if link < 0 else factors.pairwise[link])
                     for row, link in zip(factors.unary, factors.link)], dtype=bool)
    unary = factors.unary.copy()
    unary[dead & ~np.isfinite(unary).any(axis=1)] = 0.0
    return ChainFactors(unary, factors.pairwise, np.where(dead, -1, factors.link))



_MAX_GROUPS = 64  # distinct (step matrix, step matrix) kinds up to which leaves are never built one by one
_CHUNK = 256


@dataclass(frozen=True)
class _Steps:
    """Each step's matrix exp(pairwise[link] + unary), scaled to total 1: M_t = transitions[index[t]] * emissions[t]
    (column-wise). Steps of one kind share their transition, so moving many vectors through leaves is one
    matrix product per kind rather than one small product per frame."""

    index: np.ndarray  # [T] row of `transitions`: a pairwise row, or the chain-start row of ones
    transitions: np.ndarray  # [P + 1, C, C]
    emissions: np.ndarray  # [T, C]
    scale: np.ndarray  # [T] log of what the scaling took out of each step

    def matrices(self, frames: np.ndarray | slice = slice(None)) -> np.ndarray:
        out = np.take(self.transitions, self.index[frames], axis=0)
        out *= self.emissions[frames, None, :]
        return out

    def forward(self, vectors: np.ndarray, frames: np.ndarray | slice) -> np.ndarray:
        """[n, C] vectors[i] @ M_frames[i], unnormalised."""
        main, others = _kinds(self.index[frames])
        out = _times(vectors, self.transitions[main])
        for row, members in others:
            out[members] = _times(vectors[members], self.transitions[row])
        return out * self.emissions[frames]

    def backward(self, vectors: np.ndarray, frames: np.ndarray | slice) -> np.ndarray:
        """[n, C] M_frames[i] @ vectors[i], unnormalised."""
        weighted = self.emissions[frames] * vectors
        main, others = _kinds(self.index[frames])
        out = _times(weighted, self.transitions[main].T)
        for row, members in others:
            out[members] = _times(weighted[members], self.transitions[row].T)
        return out


def _times(rows: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    return rows @ matrix


def _kinds(index: np.ndarray) -> tuple[int, list[tuple[int, np.ndarray]]]:
    """The most frequent value of ``index``, and (value, positions) of each other value present."""
    counts = np.bincount(index)
    main = int(counts.argmax())
    return main, [(row, np.flatnonzero(index == row)) for row in np.flatnonzero(counts).tolist() if row != main]


def _steps(factors: ChainFactors, repeats: Repeats | None = None) -> _Steps:
    n_classes = factors.n_classes
    transitions, transition_scale = _scaled(factors.pairwise, (1, 2))
    transitions = np.concatenate([transitions, np.ones((1, n_classes, n_classes))])
    transition_scale = np.concatenate([transition_scale, [0.0]])
    index = np.where(factors.link < 0, len(factors.pairwise), factors.link)
    frames = slice(None) if repeats is None else repeats.first  # with repeats: one frame of each kind
    emissions, emission_scale = _scaled(factors.unary[frames], (1,))
    with np.errstate(divide="ignore"):  # a step's total: the transition's column sums times the emission
        total = np.log(np.einsum("nk,nk->n", transitions.sum(axis=1)[index[frames]], emissions))
    emissions /= np.exp(np.where(np.isfinite(total), total, 0.0))[:, None]
    scale = transition_scale[index[frames]] + emission_scale + total
    if repeats is not None:
        emissions, scale = emissions[repeats.kind], scale[repeats.kind]
    return _Steps(index, transitions, emissions, scale)


@dataclass(frozen=True)
class Repeats:
    """Where a chain's steps repeat, for many scans of the same chains (the CLL learner's): frames of one kind (one
    unary row, by the caller's word, and one link) have equal step matrices, and so do many nodes of the scan's
    lower levels (on all DESK frames: 23 kinds of step; 136 distinct products of two among 11,165 pairs, 620 of
    four among 5,583, 1,366 of eight among 2,792). Each distinct product is computed once, and the scan's tree
    starts from blocks of that many steps."""

    kind: np.ndarray  # [T] the kind of each frame's step
    first: np.ndarray  # [K] a frame of each kind
    levels: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]  # per level: (left, right) of each distinct node
    # (right -1: an odd last node carried up), and the distinct node of each node

    @classmethod
    def of(cls, row: np.ndarray, link: np.ndarray) -> "Repeats":
        """Frames with equal ``row`` have equal unary log-potentials in every scan these repeats are passed to."""
        link = np.asarray(link, dtype=np.int64)
        _, first, kind = np.unique(np.asarray(row, dtype=np.int64) * (link.max(initial=-1) + 2) + link + 1,
                                   return_index=True, return_inverse=True)
        ids, size, levels = kind.reshape(-1), len(first), []
        while len(ids) > 1:
            pairs = len(ids) // 2
            keys = ids[0:2 * pairs:2] * size + ids[1:2 * pairs:2]
            if len(ids) % 2:
                keys = np.append(keys, size * size + ids[-1])
            distinct, node = np.unique(keys, return_inverse=True)
            if 2 * len(distinct) > len(keys):  # mostly distinct from here up: the tree is as fast
                break
            carried = distinct >= size * size
            levels.append((np.where(carried, distinct - size * size, distinct // size),
                           np.where(carried, -1, distinct % size), node.reshape(-1)))
            ids, size = node.reshape(-1), len(distinct)
        return cls(kind.reshape(-1), first, tuple(levels))


def _blocks(steps: _Steps, repeats: Repeats | None) -> tuple[int, tuple[np.ndarray, np.ndarray]]:
    """The scan's leaves: the products of aligned blocks of ``size`` steps (the last may be shorter), scaled to total 1,
    and their log scales. Blocks are pairs of steps, or with ``repeats`` blocks of 2^levels steps built from the
    distinct products of each level."""
    if len(steps.index) == 1:
        return 1, (steps.matrices(), steps.scale)
    if repeats is None or not repeats.levels:
        return 2, _pairs(steps, len(steps.transitions[0]))
    table, scale = steps.matrices(repeats.first), steps.scale[repeats.first]
    for left, right, node in repeats.levels:
        joined = right >= 0
        products = table[left]
        products[joined] = products[joined] @ table[right[joined]]
        total = products.reshape(len(products), -1).sum(axis=1)
        with np.errstate(divide="ignore"):
            scale = scale[left] + np.where(joined, scale[right], 0.0) + np.log(total)
        table = products / np.where(total > 0, total, 1.0)[:, None, None]
    return 2 ** len(repeats.levels), (table[node], scale[node])


def _pairs(steps: _Steps, n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """The products M_{2i} M_{2i+1} (scaled to total 1) and their log scales: the tree's first level.
    M_a M_b = T_a diag(e_a) T_b diag(e_b), and T_a diag(e_a) T_b = e_a @ K with K[m] = T_a[:, m] (x) T_b[m, :]."""
    pairs = len(steps.index) // 2
    left, right = slice(0, 2 * pairs, 2), slice(1, 2 * pairs, 2)
    size = len(steps.transitions)
    main, others = _kinds(steps.index[left] * size + steps.index[right])
    if len(others) >= _MAX_GROUPS:
        products = steps.matrices(left) @ steps.matrices(right)
    else:

        def products_of(kind: int, emissions: np.ndarray) -> np.ndarray:
            first, second = steps.transitions[kind // size], steps.transitions[kind % size]
            outer = np.einsum("jm,mk->mjk", first, second).reshape(n_classes, -1)
            return _times(emissions, outer).reshape(-1, n_classes, n_classes)

        products = products_of(main, steps.emissions[left])
        for kind, members in others:
            products[members] = products_of(kind, steps.emissions[left][members])
        products *= steps.emissions[right, None, :]
    scale = steps.scale[left] + steps.scale[right]
    if len(steps.index) % 2:
        products = np.concatenate([products, steps.matrices(slice(-1, None))])
        scale = np.concatenate([scale, steps.scale[-1:]])
    total = products.reshape(len(products), -1).sum(axis=1)
    with np.errstate(divide="ignore"):
        scale += np.log(total)
    products /= np.where(total > 0, total, 1.0)[:, None, None]
    return products, scale


def _up(leaves: tuple[np.ndarray, ...], combine) -> list[tuple[np.ndarray, ...]]:
    """The tree's levels from the leaves up to the root; a level's odd last node is carried up as it is."""
    levels = [leaves]
    while len(levels[-1][0]) > 1:
        level = levels[-1]
        size = len(level[0])
        pairs = size // 2
        joined = tuple(np.empty((size - pairs, *part.shape[1:]), dtype=part.dtype) for part in level)
        combine(*(part[0:2 * pairs:2] for part in level), *(part[1:2 * pairs:2] for part in level),
                *(part[:pairs] for part in joined))
        if size % 2:
            for target, part in zip(joined, level):
                target[-1] = part[-1]
        levels.append(joined)
    return levels


def _down(levels: list[tuple[np.ndarray, ...]], root: np.ndarray, move, from_left: bool) -> np.ndarray:
    """Per node of ``levels[0]``, the value entering it from the left (``from_left``) or leaving it at the right:
    the root gets ``root``; a child on the near side gets its parent's value, the other one that value moved
    through its sibling (``move(values, sibling's level parts)``)."""
    value = root[None]
    for level in reversed(levels[:-1]):
        value = _split(value, len(level[0]), lambda values, near: move(values, *(part[near] for part in level)),
                       from_left)
    return value


def _split(value: np.ndarray, size: int, move, from_left: bool) -> np.ndarray:
    """The values of ``size`` children from their parents' ``value``: see ``_down``; ``move(values, near)`` moves
    the parents' values through the near children (an index of them)."""
    pairs = size // 2
    out = np.empty((size, *value.shape[1:]), dtype=value.dtype)
    near, far = (0, 1) if from_left else (1, 0)
    out[near:2 * pairs:2] = value[:pairs]
    out[far:2 * pairs:2] = move(value[:pairs], slice(near, 2 * pairs, 2))
    if size % 2:
        out[-1] = value[-1]
    return out


class _Dead(Exception):
    """A dead end: some frame has no possible class."""


def _product(left: np.ndarray, left_scale: np.ndarray, right: np.ndarray, right_scale: np.ndarray,
             out: np.ndarray, out_scale: np.ndarray) -> None:
    np.matmul(left, right, out=out)
    total = out.reshape(len(out), -1).sum(axis=1)
    with np.errstate(divide="ignore"):
        np.add(left_scale + right_scale, np.log(total), out=out_scale)
    out /= np.where(total > 0, total, 1.0)[:, None, None]


def _normalised(vectors: np.ndarray, totals: np.ndarray | None = None) -> np.ndarray:
    """Each vector over its total (into ``totals``); a zero total is a dead end."""
    total = vectors.sum(axis=1)
    if not (total > 0).all():
        raise _Dead
    if totals is not None:
        totals[:] = total
    return vectors / total[:, None]


def _move_forward(vectors: np.ndarray, matrices: np.ndarray, _scale: np.ndarray) -> np.ndarray:
    return _normalised((vectors[:, None, :] @ matrices)[:, 0])


def _move_backward(vectors: np.ndarray, matrices: np.ndarray, _scale: np.ndarray) -> np.ndarray:
    moved = (matrices @ vectors[:, :, None])[:, :, 0]
    return moved / moved.max(axis=1, keepdims=True)


@dataclass(frozen=True)
class _Forward:
    factors: ChainFactors  # with chain starts at the dead ends
    steps: _Steps
    size: int  # steps per block, the tree's leaves
    levels: list  # the tree: the blocks' products, then products of pairs of those, ...
    log_z: float
    entering: np.ndarray | None  # [T, C] the normalised forward vector before each step (alpha_{t-1})
    alpha: np.ndarray | None  # [T, C] after it
    moved: np.ndarray | None  # [T] the total of entering @ M_t before normalising


def _forward_once(factors: ChainFactors, vectors: bool, repeats: Repeats | None) -> _Forward:
    n_frames, n_classes = len(factors.link), factors.n_classes
    steps = _steps(factors, repeats)
    size, blocks = _blocks(steps, repeats)
    levels = _up(blocks, _product)
    root, root_scale = levels[-1][0][0], levels[-1][1][0]
    total = root[0].sum()  # the first step is a chain start: any vector summing to 1 enters it
    if not total > 0 or not np.isfinite(root_scale):
        raise _Dead
    log_z = float(root_scale + math.log(total))
    if not vectors:
        return _Forward(factors, steps, size, levels, log_z, None, None, None)
    vectors = _down(levels, np.eye(n_classes)[0], _move_forward, from_left=True)  # entering each block
    entering, alpha, moved = np.empty((n_frames, n_classes)), np.empty((n_frames, n_classes)), np.empty(n_frames)
    for position in range(size):  # through the blocks, all side by side, one step at a time
        frames = slice(position, None, size)
        count = len(moved[frames])  # a shorter last block has no step here
        entering[frames] = vectors[:count]
        alpha[frames] = vectors[:count] = _normalised(steps.forward(vectors[:count], frames), moved[frames])
    return _Forward(factors, steps, size, levels, log_z, entering, alpha, moved)


def _forward_sequential(factors: ChainFactors, vectors: bool) -> _Forward:
    """The forward pass one frame at a time, each vector normalised (as ``Filter``): for chains whose block
    products underflow although every frame stays possible (probabilities below e^-745 that ``Filter`` keeps)."""
    steps = _steps(factors)
    n_frames, n_classes = len(factors.link), factors.n_classes
    levels = [(steps.matrices(slice(0, 1)), steps.scale[:1])]  # one leaf standing for all steps: passes go frame by frame
    entering, alpha, moved = np.empty((n_frames, n_classes)), np.empty((n_frames, n_classes)), np.empty(n_frames)
    vector = np.eye(n_classes)[:1]
    for frame in range(n_frames):
        entering[frame] = vector[0]
        try:
            alpha[frame] = vector[0] = _normalised(steps.forward(vector, slice(frame, frame + 1)), moved[frame:frame + 1])[0]
        except _Dead:
            raise FloatingPointError(f"the chain's forward pass underflows at frame {frame} even after restarting "
                                     "at its dead ends") from None
    log_z = float(steps.scale.sum() + np.log(moved).sum())
    if not vectors:
        return _Forward(factors, steps, n_frames, levels, log_z, None, None, None)
    return _Forward(factors, steps, n_frames, levels, log_z, entering, alpha, moved)


def _forward(factors: ChainFactors, vectors: bool = True, repeats: Repeats | None = None) -> _Forward:
    """The up-sweep and (with ``vectors``) the forward vectors, dead ends turned into chain starts; where the
    scan's block products underflow, the same pass frame by frame."""
    try:
        return _forward_once(factors, vectors, repeats)
    except _Dead:
        pass
    restarted = _restarted(factors)
    try:
        return _forward_once(restarted, vectors, None)  # its chain starts are not those of the repeats
    except _Dead:
        return _forward_sequential(restarted, vectors)


def _backward(forward: _Forward) -> np.ndarray:
    """[T, C] the backward vector after each step (beta_t, each scaled to max 1)."""
    n_frames, n_classes, size = len(forward.factors.link), forward.factors.n_classes, forward.size
    vectors = _down(forward.levels, np.ones(n_classes), _move_backward, from_left=False)  # leaving each block
    beta = np.empty((n_frames, n_classes))
    for position in reversed(range(size)):
        frames = slice(position, None, size)
        count = len(beta[frames])  # a shorter last block keeps its vector until its last step
        beta[frames] = vectors[:count]
        moved = forward.steps.backward(vectors[:count], frames)
        vectors[:count] = moved / moved.max(axis=1, keepdims=True)
    return beta


def _smoothed(forward: _Forward) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The marginals [T, C], the backward vectors [T, C] and each frame's sum of alpha_t * beta_t [T]."""
    beta = _backward(forward)
    gamma = forward.alpha * beta
    overlap = gamma.sum(axis=1)
    return gamma / overlap[:, None], beta, overlap


def filtered(factors: ChainFactors) -> np.ndarray:
    """[T, C] log p(y_t | frames of its chain up to t) (online)."""
    if len(factors.link) == 0:
        return np.zeros((0, factors.n_classes))
    with np.errstate(divide="ignore"):
        return np.log(_forward(factors).alpha)


def smoothed(factors: ChainFactors) -> np.ndarray:
    """[T, C] log p(y_t | all frames of its chain) (forward-backward)."""
    if len(factors.link) == 0:
        return np.zeros((0, factors.n_classes))
    with np.errstate(divide="ignore"):
        return np.log(_smoothed(_forward(factors))[0])


def log_partition(factors: ChainFactors) -> float:
    """Sum over chains of log Z (a chain cut by a dead end counts as its pieces)."""
    if len(factors.link) == 0:
        return 0.0
    return _forward(factors, vectors=False).log_z


@dataclass(frozen=True)
class Expectations:
    log_z: float
    unary: np.ndarray  # [T, C] p(y_t = k | its chain)
    pairwise: np.ndarray  # [P, C, C] summed over the frames t each row links: p(y_{t-1} = j, y_t = k | chain)


def expectations(factors: ChainFactors, repeats: Repeats | None = None) -> Expectations:
    """log Z and the marginals that the gradient of the conditional log-likelihood needs (``repeats``: where the
    factors' steps repeat, to compute each distinct product once)."""
    n_frames, n_classes, n_rows = len(factors.link), factors.n_classes, len(factors.pairwise)
    if n_frames == 0:
        return Expectations(0.0, np.zeros((0, n_classes)), np.zeros((n_rows, n_classes, n_classes)))
    forward = _forward(factors, repeats=repeats)
    gamma, beta, overlap = _smoothed(forward)
    steps = forward.steps
    # p(y_{t-1} = j, y_t = k) = alpha_{t-1}(j) M_t(j, k) beta_t(k) / n_t, M_t = transitions[link] * emissions[t],
    # with n_t = sum_k (alpha_{t-1} M_t)(k) beta_t(k) = moved_t * (alpha_t . beta_t)
    weighted = forward.entering / (forward.moved * overlap)[:, None]
    following = steps.emissions * beta
    totals = np.zeros((n_rows, n_classes, n_classes))
    main, others = _kinds(steps.index)
    for row, members in [(main, steps.index == main), *others]:
        if row < n_rows:
            totals[row] = steps.transitions[row] * (weighted[members].T @ following[members])
    return Expectations(forward.log_z, gamma, totals)


def count_covariance(factors: ChainFactors, row: np.ndarray, n_rows: int, repeats: Repeats | None = None) -> np.ndarray:
    """[D, D], D = n_rows * C + P * C * C: the covariance, under the chains' distribution, of their counts: frames of
    each row (``row[t]`` in [0, n_rows)) with each class, then linked pairs of each pairwise row with each class
    pair. It is the Hessian of log Z when frames of one row share their unary log-potentials (the CLL learner's
    Newton metric). Exact: same-frame terms per kind of frame, cross-frame terms by a recursion over the chain
    (``_cross_covariance``). ``repeats``: as for ``expectations``."""
    forward = _forward(factors, repeats=repeats)
    factors = forward.factors  # with chain starts at dead ends, as the marginals have them
    gamma, beta, _ = _smoothed(forward)
    linked = factors.link >= 0
    reach = forward.steps.matrices() * beta[:, None, :]
    total = reach.sum(axis=2, keepdims=True)
    after = np.divide(reach, total, out=np.zeros_like(reach), where=total > 0)  # p(y_t = j | y_{t-1} = i, chain)
    after[~linked] = 0.0
    pairs = np.zeros_like(after)  # p(y_{t-1} = i, y_t = j | chain)
    pairs[1:] = gamma[:-1, :, None] * after[1:]
    counts = _Counts(np.asarray(row, dtype=np.int64), factors.link, n_rows, factors.n_classes, len(factors.pairwise))
    cross = _cross_covariance(gamma, pairs, after, counts)
    return _same_frame_covariance(gamma, pairs, counts) + cross + cross.T


@dataclass(frozen=True)
class _Counts:
    """Where each frame's counts sit among the D counts of ``count_covariance``."""

    row: np.ndarray  # [T]
    link: np.ndarray  # [T], -1: no pair counts
    n_rows: int
    n_classes: int
    n_pairwise: int

    @property
    def size(self) -> int:
        return self.n_rows * self.n_classes + self.n_pairwise * self.n_classes ** 2

    def unary(self, row: np.ndarray) -> np.ndarray:
        """[..., C] the counts (row, class) of frames of ``row``."""
        return np.asarray(row)[..., None] * self.n_classes + np.arange(self.n_classes)

    def pair(self, link: np.ndarray) -> np.ndarray:
        """[..., C * C] the counts (pairwise row, class before, class after) of frames linked by ``link`` (>= 0)."""
        return self.n_rows * self.n_classes + np.asarray(link)[..., None] * self.n_classes ** 2 + np.arange(self.n_classes ** 2)


def _same_frame_covariance(gamma: np.ndarray, pairs: np.ndarray, counts: _Counts) -> np.ndarray:
    """sum_t Cov(counts of frame t): per kind of frame (row, pairwise row), the covariance of the frame's local counts
    (its class, and its class pair if linked) summed over the frames of that kind."""
    n_classes = counts.n_classes
    covariance = np.zeros((counts.size, counts.size))
    kinds, kind = np.unique(np.stack([counts.row, counts.link], axis=1), axis=0, return_inverse=True)
    kind = kind.reshape(-1)
    for index, (row, link) in enumerate(kinds.tolist()):
        members = kind == index
        local = gamma[members] if link < 0 else np.concatenate(
            [gamma[members], pairs[members].reshape(-1, n_classes ** 2)], axis=1)
        mean = local.sum(axis=0)
        block = np.diag(mean) - local.T @ local
        if link >= 0:  # a pair (i, k) also counts class k
            pair_of = n_classes + np.arange(n_classes ** 2)
            block[pair_of % n_classes, pair_of] += mean[pair_of]
            block[pair_of, pair_of % n_classes] += mean[pair_of]
        at = counts.unary(row) if link < 0 else np.concatenate([counts.unary(row), counts.pair(link)])
        covariance[np.ix_(at, at)] += block
    return covariance


def _cross_covariance(gamma: np.ndarray, pairs: np.ndarray, after: np.ndarray, counts: _Counts) -> np.ndarray:
    """X = sum over frames s < t of one chain of Cov(counts of s, counts of t) (rows: s's counts), by the backward
    recursion for K_s[k] = E[counts of the frames after s | y_s = k] - their mean:
        K_{t-1}[i] = sum_j after_t[i, j] (counts of (i, j) at t + K_t[j]) - mean counts of t,
        X = sum_s psi_s^T K_s,  psi_s[k] = gamma_s(k) e(s's count of k) + sum_i pairs_s(i, k) e(s's count of (i, k)).
    Blocks of frames run side by side, one numpy call per position in a block, each from K = 0 at its end; with
    S_s = p(y at the block's end | y_s), the true K_s = K_s(local) + S_s K(block's end), so X adds
    sum_b (sum_{s in b} psi_s^T S_s) K(end of b), and one loop over the blocks finds those K from what each block
    passes on (its K before its first frame, and its S there)."""
    n_frames, n_classes = gamma.shape
    size, n_unary = counts.size, counts.n_rows * counts.n_classes
    length = max(1, 4 * math.isqrt(n_frames))
    n_blocks = -(-n_frames // length)
    pad = n_blocks * length - n_frames

    def by_position(values: np.ndarray, fill: float = 0) -> np.ndarray:
        """[T, ...] -> [L, B, ...]: frame b * L + i at [i, b]; padding frames after the end (nothing, linked to nothing)."""
        values = np.concatenate([values, np.full((pad, *values.shape[1:]), fill, dtype=values.dtype)])
        return np.ascontiguousarray(values.reshape(n_blocks, length, *values.shape[1:]).swapaxes(0, 1))

    after, pairs, gamma = by_position(after), by_position(pairs), by_position(gamma)
    link = by_position(counts.link, -1)
    gamma_linked = gamma * (link >= 0)[..., None]
    unary_columns = counts.unary(by_position(counts.row))  # [L, B, C]
    pair_columns = counts.pair(np.maximum(link, 0)).reshape(length, n_blocks, n_classes, n_classes)
    one_link = counts.n_pairwise == 1  # then every linked frame has the same pair counts: slices, not indices
    blocks, classes = np.arange(n_blocks)[:, None], np.arange(n_classes)
    # flat positions in a [B, C, D] state: (b, i, (row, j)) and (b, i, (link, i, j)), for [L, B, C(i), C(j)]
    state_rows = ((blocks * n_classes + classes) * size)[None, :, :, None]
    unary_at = state_rows + unary_columns[:, :, None, :]
    pair_at = state_rows + pair_columns
    step_at = np.concatenate([unary_at, pair_at], axis=3).reshape(length, -1)
    step_add = np.concatenate([after - gamma_linked[:, :, None, :], after], axis=3).reshape(length, -1)

    def step(state: np.ndarray, i: int) -> np.ndarray:
        """K before the frames at position i from K at them: sum_j after (counts + K) - mean counts."""
        moved = after[i] @ state
        np.add.at(moved.reshape(-1), step_at[i], step_add[i])
        mean = pairs[i].reshape(n_blocks, 1, -1)
        if one_link:
            moved[:, :, n_unary:] -= mean
        else:
            moved[blocks[:, :, None], classes[:, None], pair_columns[i].reshape(n_blocks, 1, -1)] -= mean
        return moved

    from scipy import sparse  # learning only: recognising a chain needs numpy alone

    width = n_blocks * n_classes  # frames' unary counts at one position, weighted by gamma: a sparse [n_unary, B * C]
    gathered = sparse.csc_matrix((gamma.reshape(-1), (unary_columns.reshape(-1), np.arange(length * width))),
                                 shape=(n_unary, length * width))
    local_unary = np.zeros((n_unary, size))
    local_pair = np.zeros((counts.n_pairwise, n_classes, n_classes, size))
    to_end = np.zeros((n_blocks, size, n_classes))  # sum_{s in b} psi_s^T S_s
    to_end_at = (((blocks * size + unary_columns) * n_classes)[..., None] + classes).reshape(length, -1)  # (b, (row, k), m)
    state = np.zeros((n_blocks, n_classes, size))
    through = np.broadcast_to(np.eye(n_classes), (n_blocks, n_classes, n_classes)).copy()
    for i in reversed(range(length)):
        local_unary += gathered[:, i * width:(i + 1) * width] @ state.reshape(width, size)
        np.add.at(to_end.reshape(-1), to_end_at[i], (gamma[i][:, :, None] * through).reshape(-1))
        weighted = pairs[i][:, :, :, None] * through[:, None, :, :]  # [b, i, k, m]
        for pairwise, members in [(0, slice(None))] if one_link else _kinds_present(link[i]):
            local_pair[pairwise] += np.matmul(pairs[i][members].transpose(2, 1, 0),
                                              state[members].transpose(1, 0, 2)).transpose(1, 0, 2)
            rows = slice(n_unary, None) if one_link else pair_columns[i][members].reshape(-1, n_classes ** 2)
            to_end[blocks[members] if not one_link else slice(None), rows] += weighted[members].reshape(-1, n_classes ** 2, n_classes)
        state = step(state, i)
        through = after[i] @ through
    at_end = np.zeros((n_blocks, n_classes, size))  # the true K at each block's last frame
    for block in reversed(range(1, n_blocks)):
        at_end[block - 1] = state[block] + through[block] @ at_end[block]
    local = np.concatenate([local_unary, local_pair.reshape(-1, size)])
    return local + to_end.transpose(1, 0, 2).reshape(size, -1) @ at_end.reshape(-1, size)


def _kinds_present(link: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """(pairwise row, positions) of each pairwise row that ``link`` uses."""
    return [(row, np.flatnonzero(link == row)) for row in np.unique(link[link >= 0]).tolist()]


def _max_product(left: np.ndarray, right: np.ndarray, out: np.ndarray) -> None:
    """(max, +) matrix products."""
    out[:] = left[:, :, :1] + right[:, :1, :]
    for middle in range(1, left.shape[2]):
        np.maximum(out, left[:, :, middle, None] + right[:, None, middle, :], out=out)


def _compose(left: np.ndarray, right: np.ndarray, out: np.ndarray) -> None:
    """Back-pointer maps: the class before the left node's steps, given the class after the right node's."""
    out[:] = np.take_along_axis(left, right, axis=1)


def _move_best(best: np.ndarray, matrices: np.ndarray) -> np.ndarray:
    moved = (best[:, :, None] + matrices).max(axis=1)
    top = moved.max(axis=1, keepdims=True)
    if not np.isfinite(top).all():
        raise _Dead
    return moved - top


def _viterbi_once(factors: ChainFactors) -> np.ndarray:
    n_classes, link = factors.n_classes, factors.link
    steps = np.where(link[:, None, None] < 0, 0.0, factors.pairwise[np.maximum(link, 0)]) + factors.unary[:, None, :]
    levels = _up((steps,), _max_product)
    start = np.full(n_classes, -np.inf)
    start[0] = 0.0  # the first step is a chain start: its rows are all equal
    best = _down(levels, start, _move_best, from_left=True)
    candidates = best[:, :, None] + steps
    pointers = candidates.argmax(axis=1)
    final = candidates[-1].max(axis=0)
    if not np.isfinite(candidates.max(axis=1)).any(axis=1).all():
        raise _Dead
    maps = _up((pointers,), _compose)

    def back(classes: np.ndarray, right: np.ndarray) -> np.ndarray:
        return np.take_along_axis(right, classes[:, None], axis=1)[:, 0]

    return _down(maps, np.int64(final.argmax()), back, from_left=False)


def viterbi(factors: ChainFactors) -> np.ndarray:
    """[T] int64 the most probable class path of each chain (ties: the lower class)."""
    if len(factors.link) == 0:
        return np.zeros(0, dtype=np.int64)
    try:
        return _viterbi_once(factors)
    except _Dead:
        return _viterbi_once(_restarted(factors))


@dataclass(frozen=True)
class Decoded:
    """A decoded chain: class probabilities, the predicted classes and where a dead end restarted the chain."""

    probabilities: np.ndarray  # [T, C] filter: p(y_t | frames up to t); viterbi: p(y_t | all frames of its chain)
    path: np.ndarray  # [T] int64 filter: each frame's most probable class; viterbi: the most probable path
    restarts: np.ndarray  # [R] int64 the frames where no class was possible given the previous ones: a new chain


def dead_ends(original: ChainFactors, restarted: ChainFactors) -> np.ndarray:
    """[R] the frames that ``restarted`` starts anew (dead ends) and the frames no class is possible at."""
    return np.flatnonzero((restarted.link != original.link) | ~np.isfinite(original.unary).any(axis=1))


def decode(factors: ChainFactors, kind: str) -> Decoded:
    """Decode online (``filter``, as ``Filter`` does frame by frame) or offline (``viterbi``, with the
    forward-backward marginals as probabilities), restarting the chain at each dead end as ``Filter`` does."""
    if kind not in ("filter", "viterbi"):
        raise ValueError(f"unknown decoding {kind!r}: filter or viterbi")
    if len(factors.link) == 0:
        return Decoded(np.zeros((0, factors.n_classes)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    forward = _forward(factors)
    restarts = dead_ends(factors, forward.factors)
    with np.errstate(divide="ignore"):  # exp of the log-probabilities `filtered` and `smoothed` give: the same numbers
        if kind == "filter":
            probabilities = np.exp(np.log(forward.alpha))
            return Decoded(probabilities, probabilities.argmax(axis=1), restarts)
        return Decoded(np.exp(np.log(_smoothed(forward)[0])), viterbi(forward.factors), restarts)


def chain_starts(episode: np.ndarray, split: np.ndarray | None = None) -> np.ndarray:
    """bool [T]: where a chain starts in frames listed in episode order: the first frame, and wherever the
    episode (or the split, within an episode) changes from the previous row."""
    episode = np.asarray(episode)
    starts = np.ones(len(episode), dtype=bool)
    starts[1:] = episode[1:] != episode[:-1]
    if split is not None:
        split = np.asarray(split)
        starts[1:] |= split[1:] != split[:-1]
    return starts


def path_score(factors: ChainFactors, labels: np.ndarray) -> float:
    """The log-potential of one class path: sum_t unary[t, y_t] + sum of the pairwise terms that link frames
    (log p(path) = path_score - log_partition)."""
    labels = np.asarray(labels, dtype=np.int64)
    frames = np.arange(len(labels))
    joined = np.flatnonzero(factors.link >= 0)
    return float(factors.unary[frames, labels].sum()
                 + factors.pairwise[factors.link[joined], labels[joined - 1], labels[joined]].sum())
