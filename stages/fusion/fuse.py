"""What every recogniser path shares: the MLN input of PriorLayer, fusion (eq. 16) and a decoded method's chain
(conflate over a workdir, `Recognizer` over a model file, cross-validation over folds), decoded by
stages/fusion/decoding.py."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from mlnseq.catalog.methods import FUSED, NETWORKS, Method, MLNMode, PaperFloor, Prior
from mlnseq.mln import chain

if TYPE_CHECKING:
    from mlnseq.mln.factors import MLNFactors

EPSILON = 1e-7  # keeps eq. 16 defined when one side is exactly 0 and the other exactly 1


# --- the MLN ----------------------------------------------------------------------------------------


def prior_input(scores: np.ndarray, kind: Prior, floor: PaperFloor) -> np.ndarray:
    """The c2c input of PriorLayer: the MLN class weights as the authors passed them (floored by ``floor``), or
    log-probs."""
    from mlnseq.mln import classifier

    if kind == Prior.PAPER:
        return np.asarray(classifier.paper_prior(scores, floor), dtype=np.float32)
    return np.asarray(classifier.class_log_probs(scores, MLNMode.EXACT, floor), dtype=np.float32)


# --- fusion -----------------------------------------------------------------------------------------


def conflation(p_network: np.ndarray, p_mln: np.ndarray) -> np.ndarray:
    """Eq. 16 per class on [n, C] probabilities: P_L·P_K / (P_L·P_K + (1 − P_L)·(1 − P_K)).

    The values are eq. 16 as it stands, not renormalised to sum to 1 (the argmax is the same either way).
    """
    a = np.clip(np.asarray(p_network, dtype=np.float64), EPSILON, 1 - EPSILON)
    b = np.clip(np.asarray(p_mln, dtype=np.float64), EPSILON, 1 - EPSILON)
    return a * b / (a * b + (1 - a) * (1 - b))


def fuse(method: str, p_network: np.ndarray | None, p_mln: np.ndarray | None) -> np.ndarray:
    """A method's per-frame class probabilities, undecoded: the network, the MLN, or eq. 16 of the two."""
    if method == Method.MLN:
        return p_mln
    if method in NETWORKS:
        return p_network
    return conflation(p_network, p_mln)


# --- decoding ---------------------------------------------------------------------------------------


def frame_factor(method: str, mln_unary: np.ndarray, log_p_network: np.ndarray | None, weight: float) -> np.ndarray:
    """A decoded method's per-frame log-potentials: the MLN's per-frame factor (mln, conflation, combined)
    plus ``weight`` times the network's log-probabilities (every method but mln)."""
    factor = mln_unary if method == "mln" or method in FUSED else np.zeros_like(mln_unary)
    return factor if method == "mln" else factor + weight * np.asarray(log_p_network, dtype=np.float64)


def chain_of(method: str, mln: MLNFactors, evidence: np.ndarray, starts: np.ndarray,
             log_p_network: np.ndarray | None, weight: float, start: np.ndarray | None = None) -> chain.ChainFactors:
    """The chain a decoded method runs: its frame factors and the MLN's transition factors, and the start
    distribution ``start`` (log [C]) at each chain's first frame, if given."""
    from mlnseq.mln.lag import with_start

    factors = mln.chain(evidence, starts)
    return with_start(replace(factors, unary=frame_factor(method, factors.unary, log_p_network, weight)), start)


def restart_note(name: str, restarts: Sequence[tuple[Any, int]], shown: int = 5) -> str:
    """One line naming where a decoded method's chain restarted: (episode, frame) of each dead end."""
    where = ", ".join(f"episode {episode} frame {frame}" for episode, frame in restarts[:shown])
    more = f" and {len(restarts) - shown} more" if len(restarts) > shown else ""
    return (f"{name}: the chain restarted at {len(restarts)} frame(s) that no allowed transition reaches (a missed "
            f"episode boundary, or evidence that breaks a hard rule): {where}{more}")
