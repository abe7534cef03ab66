"""The moments of the chains' distribution that only the CLL learner uses (stages/mln/cll.py): the marginals its
gradient needs and the exact covariance of the formula counts (its Newton metric)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mlnseq.mln.chain_factors import ChainFactors
from mlnseq.mln.chain_scan import Repeats, _forward, _kinds, _smoothed

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


CHUNK_FRAMES = 40_000  # frames whose covariance is found at once (about 2 kB of scratch each): whole chains


def count_covariance(factors: ChainFactors, row: np.ndarray, n_rows: int, repeats: Repeats | None = None) -> np.ndarray:
    """[D, D], D = n_rows * C + P * C * C: the covariance, under the chains' distribution, of their counts: frames of
    each row (``row[t]`` in [0, n_rows)) with each class, then linked pairs of each pairwise row with each class
    pair. It is the Hessian of log Z when frames of one row share their unary log-potentials (the CLL learner's
    Newton metric). Exact: same-frame terms per kind of frame, cross-frame terms by a recursion over the chain
    (``_cross_covariance``). ``repeats``: as for ``expectations``. Over ``CHUNK_FRAMES`` frames, the sum of the
    covariances of pieces of whole chains (independent, their counts' covariances add), so that the scratch memory is
    bounded by the piece rather than the frames."""
    pieces = _pieces(factors.link)
    if len(pieces) == 1:
        return _count_covariance(factors, row, n_rows, repeats)
    total = None
    for piece in pieces:
        part = ChainFactors(factors.unary[piece], factors.pairwise, factors.link[piece])
        covariance = _count_covariance(part, np.asarray(row)[piece], n_rows, None)
        total = covariance if total is None else total + covariance
    return total


def _pieces(link: np.ndarray) -> list[slice]:
    """Consecutive runs of whole chains of at most CHUNK_FRAMES frames (a longer chain alone), covering every frame."""
    starts = np.flatnonzero(np.asarray(link) < 0).tolist() + [len(link)]
    pieces, begin = [], 0
    for start, end in zip(starts, starts[1:]):
        if end - begin > CHUNK_FRAMES and start > begin:
            pieces.append(slice(begin, start))
            begin = start
    return pieces + [slice(begin, len(link))]


def _count_covariance(factors: ChainFactors, row: np.ndarray, n_rows: int, repeats: Repeats | None) -> np.ndarray:
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
        return (self.n_rows * self.n_classes + np.asarray(link)[..., None] * self.n_classes ** 2
                + np.arange(self.n_classes ** 2))


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


@dataclass(frozen=True)
class _Positions:
    """A chain's frames in B blocks of L, by position in their block (frame b * L + i at [i, b]; padding frames
    after the end, linked to nothing), and where each position's counts sit in a [B, C, D] state."""

    length: int
    n_blocks: int
    after: np.ndarray  # [L, B, C, C]
    pairs: np.ndarray  # [L, B, C, C]
    gamma: np.ndarray  # [L, B, C]
    link: np.ndarray  # [L, B]
    unary_columns: np.ndarray  # [L, B, C]
    pair_columns: np.ndarray  # [L, B, C, C]
    step_at: np.ndarray  # [L, B * C * 2C] flat positions of (b, i, (row, j)) and (b, i, (link, i, j))
    step_add: np.ndarray  # [L, B * C * 2C] what a step adds there
    one_link: bool  # every linked frame has the same pair counts: slices, not indices
    blocks: np.ndarray  # [B, 1]
    classes: np.ndarray  # [C]

    @classmethod
    def of(cls, gamma: np.ndarray, pairs: np.ndarray, after: np.ndarray, counts: _Counts) -> _Positions:
        n_frames, n_classes = gamma.shape
        length = max(1, 4 * math.isqrt(n_frames))
        n_blocks = -(-n_frames // length)
        pad = n_blocks * length - n_frames

        def by_position(values: np.ndarray, fill: float = 0) -> np.ndarray:
            """[T, ...] -> [L, B, ...]."""
            values = np.concatenate([values, np.full((pad, *values.shape[1:]), fill, dtype=values.dtype)])
            return np.ascontiguousarray(values.reshape(n_blocks, length, *values.shape[1:]).swapaxes(0, 1))

        after, pairs, gamma = by_position(after), by_position(pairs), by_position(gamma)
        link = by_position(counts.link, -1)
        gamma_linked = gamma * (link >= 0)[..., None]
        unary_columns = counts.unary(by_position(counts.row))
        pair_columns = counts.pair(np.maximum(link, 0)).reshape(length, n_blocks, n_classes, n_classes)
        blocks, classes = np.arange(n_blocks)[:, None], np.arange(n_classes)
        state_rows = ((blocks * n_classes + classes) * counts.size)[None, :, :, None]
        step_at = np.concatenate([state_rows + unary_columns[:, :, None, :], state_rows + pair_columns],
                                 axis=3).reshape(length, -1)
        step_add = np.concatenate([after - gamma_linked[:, :, None, :], after], axis=3).reshape(length, -1)
        return cls(length, n_blocks, after, pairs, gamma, link, unary_columns, pair_columns, step_at, step_add,
                   counts.n_pairwise == 1, blocks, classes)

    def step(self, state: np.ndarray, i: int, n_unary: int) -> np.ndarray:
        """K before the frames at position i from K at them: sum_j after (counts + K) - mean counts."""
        moved = self.after[i] @ state
        np.add.at(moved.reshape(-1), self.step_at[i], self.step_add[i])
        mean = self.pairs[i].reshape(self.n_blocks, 1, -1)
        if self.one_link:
            moved[:, :, n_unary:] -= mean
        else:
            moved[self.blocks[:, :, None], self.classes[:, None], self.pair_columns[i].reshape(self.n_blocks, 1, -1)] \
                -= mean
        return moved


def _cross_covariance(gamma: np.ndarray, pairs: np.ndarray, after: np.ndarray, counts: _Counts) -> np.ndarray:
    """X = sum over frames s < t of one chain of Cov(counts of s, counts of t) (rows: s's counts), by the backward
    recursion for K_s[k] = E[counts of the frames after s | y_s = k] - their mean:
        K_{t-1}[i] = sum_j after_t[i, j] (counts of (i, j) at t + K_t[j]) - mean counts of t,
        X = sum_s psi_s^T K_s,  psi_s[k] = gamma_s(k) e(s's count of k) + sum_i pairs_s(i, k) e(s's count of (i, k)).
    Blocks of frames run side by side, one numpy call per position in a block, each from K = 0 at its end; with
    S_s = p(y at the block's end | y_s), the true K_s = K_s(local) + S_s K(block's end), so X adds
    sum_b (sum_{s in b} psi_s^T S_s) K(end of b), and one loop over the blocks finds those K from what each block
    passes on (its K before its first frame, and its S there)."""
    from scipy import sparse  # learning only: recognising a chain needs numpy alone

    at = _Positions.of(gamma, pairs, after, counts)
    n_classes, size, n_unary = gamma.shape[1], counts.size, counts.n_rows * counts.n_classes
    length, n_blocks, blocks, classes, one_link = at.length, at.n_blocks, at.blocks, at.classes, at.one_link
    width = n_blocks * n_classes  # frames' unary counts at one position, weighted by gamma: a sparse [n_unary, B * C]
    gathered = sparse.csc_matrix((at.gamma.reshape(-1), (at.unary_columns.reshape(-1), np.arange(length * width))),
                                 shape=(n_unary, length * width))
    local_unary = np.zeros((n_unary, size))
    local_pair = np.zeros((counts.n_pairwise, n_classes, n_classes, size))
    to_end = np.zeros((n_blocks, size, n_classes))  # sum_{s in b} psi_s^T S_s
    # (b, (row, k), m)
    to_end_at = (((blocks * size + at.unary_columns) * n_classes)[..., None] + classes).reshape(length, -1)
    state = np.zeros((n_blocks, n_classes, size))
    through = np.broadcast_to(np.eye(n_classes), (n_blocks, n_classes, n_classes)).copy()
    for i in reversed(range(length)):
        local_unary += gathered[:, i * width:(i + 1) * width] @ state.reshape(width, size)
        np.add.at(to_end.reshape(-1), to_end_at[i], (at.gamma[i][:, :, None] * through).reshape(-1))
        weighted = at.pairs[i][:, :, :, None] * through[:, None, :, :]  # [b, i, k, m]
        for pairwise, members in [(0, slice(None))] if one_link else _kinds_present(at.link[i]):
            local_pair[pairwise] += np.matmul(at.pairs[i][members].transpose(2, 1, 0),
                                              state[members].transpose(1, 0, 2)).transpose(1, 0, 2)
            rows = slice(n_unary, None) if one_link else at.pair_columns[i][members].reshape(-1, n_classes ** 2)
            to_end[blocks[members] if not one_link else slice(None), rows] += \
                weighted[members].reshape(-1, n_classes ** 2, n_classes)
        state = at.step(state, i, n_unary)
        through = at.after[i] @ through
    at_end = np.zeros((n_blocks, n_classes, size))  # the true K at each block's last frame
    for block in reversed(range(1, n_blocks)):
        at_end[block - 1] = state[block] + through[block] @ at_end[block]
    local = np.concatenate([local_unary, local_pair.reshape(-1, size)])
    return local + to_end.transpose(1, 0, 2).reshape(size, -1) @ at_end.reshape(-1, size)


def _kinds_present(link: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """(pairwise row, positions) of each pairwise row that ``link`` uses."""
    return [(row, np.flatnonzero(link == row)) for row in np.unique(link[link >= 0]).tolist()]
