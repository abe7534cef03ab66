"""The parallel scan behind exact chain inference: one numpy call per level of a binary tree over the steps.

Going up, each node holds the product of its steps' matrices (scaled by its total); going down, each node
receives the forward vector entering it (the left child its parent's, the right child that vector moved
through its left sibling) and the backward vector leaving it (mirrored). Viterbi is the same scan in the
(max, +) semiring, and its backtracking a scan over the composition of the back-pointer maps. The public
functions are in stages/mln/chain.py; the CLL learner's moments in stages/mln/chain_moments.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mlnseq.mln.chain_factors import ChainFactors, _restarted, _scaled

_MAX_GROUPS = 64  # distinct (step matrix, step matrix) kinds up to which leaves are never built one by one


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
    # one leaf standing for all steps: passes go frame by frame
    levels = [(steps.matrices(slice(0, 1)), steps.scale[:1])]
    entering, alpha, moved = np.empty((n_frames, n_classes)), np.empty((n_frames, n_classes)), np.empty(n_frames)
    vector = np.eye(n_classes)[:1]
    for frame in range(n_frames):
        entering[frame] = vector[0]
        try:
            alpha[frame] = vector[0] = _normalised(steps.forward(vector, slice(frame, frame + 1)),
                                                   moved[frame:frame + 1])[0]
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
