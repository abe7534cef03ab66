"""What a model's chain makes of one recording, for an audit: its most probable phases and how surely it takes each
step of them (the log-probability of each frame's phase given the previous frame's and its own evidence); live, the
same step by step (``StepLikelihood``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlnseq.mln.chain_factors import ChainFactors

IMPOSSIBLE = -50.0  # the log-likelihood of a step the chain forbids


@dataclass(frozen=True)
class Decoded:
    """One recording as the model decoded it: its phases, predicate values, and what the chain says of them."""

    path: np.ndarray  # [T] the most probable phases (viterbi)
    evidence: np.ndarray | None  # [T, W] predicate values; None: a model without predicates
    likelihood: np.ndarray | None = None  # [T] log p(each step of the path); None: no chain


def piece(factors: ChainFactors, span: slice) -> ChainFactors:
    """The factors of the frames ``span`` alone, a chain starting at its first frame."""
    link = factors.link[span].copy()
    if len(link):
        link[0] = -1
    return ChainFactors(factors.unary[span], factors.pairwise, link)


def step_likelihood(factors: ChainFactors, path: np.ndarray) -> np.ndarray:
    """Per frame, log p(its decoded class | the previous frame's, its own evidence) under the chain's factors: how
    surely the chain takes each step of ``path`` (0: certainly; a chain's first frame: its unary alone)."""
    rows = np.asarray(factors.unary, dtype=np.float64).copy()
    steps = np.flatnonzero(factors.link >= 0)
    rows[steps] += factors.pairwise[factors.link[steps], path[steps - 1]]
    top = rows.max(axis=1, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):  # a frame every class is forbidden at: IMPOSSIBLE
        total = np.log(np.exp(rows - top).sum(axis=1)) + top[:, 0]
        picked = rows[np.arange(len(path)), path]
        return np.where(np.isfinite(picked) & np.isfinite(total), picked - total, IMPOSSIBLE)


def decoded_path(factors: ChainFactors) -> np.ndarray:
    """The most probable phases of one recording's chain (viterbi, restarting at dead ends as the decoders do)."""
    from mlnseq.fusion import decoding as decoders

    return decoders.decode(factors, "viterbi").path


def decoded(factors: ChainFactors, evidence: np.ndarray | None, path: np.ndarray | None = None) -> Decoded:
    """One recording's chain decoded for an audit: viterbi (unless ``path`` is given) and each step's likelihood."""
    path = decoded_path(factors) if path is None else path
    return Decoded(path, evidence, step_likelihood(factors, path))
