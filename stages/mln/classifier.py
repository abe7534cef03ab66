"""The MLN classifier: per-frame class scores from learned weights, and the authors' use of them.

A frame's score for class k is the MLN's log-potential with Topic(C<k>) true and the other Topic
atoms false, minus that with every Topic atom false; for `body => Topic(C<k>)` this adds the
weight to class k exactly when the body holds. Hard formulas count with ``HARD_WEIGHT``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.methods import PaperFloor
from mlnseq.mln.distinct_rows import distinct_rows

HARD_WEIGHT = 1000.0  # a hard formula's weight in the scores: far above any learned weight
MODES = ("paper", "exact")


def class_scores(predicates: pl.DataFrame, weights: pl.DataFrame, classes: int | Sequence[str]) -> np.ndarray:
    """[n_frames, n_classes] float64: per frame, sum of the weights of the formulas whose body (the
    evidence part) is true in that frame and whose head is Topic(C<k>) — i.e. the formulas that are
    satisfied only if the class is k. Row order = predicates' row order. Temporal formulas (Next) are
    left out: they are factors between frames (mlnseq.mln.factors). ``classes``: the frames' class names in
    label order, or their number (formulas naming classes as C<k> only)."""
    from mlnseq.mln.factors import frame_scores, parse_weights

    words = tuple(artifacts.feature_columns(predicates))
    evidence = predicates.select(words).to_numpy().astype(bool) if words else np.zeros((predicates.height, 0), bool)
    per_frame = [f for f in parse_weights(weights, words, classes) if not f.temporal]
    n_classes = classes if isinstance(classes, int) else len(classes)
    unique, inverse = distinct_rows(evidence)
    return frame_scores(per_frame, unique, words, n_classes, hard_weight=HARD_WEIGHT)[inverse]


def paper_prior(scores: np.ndarray, floor: PaperFloor) -> np.ndarray:
    """The class weights as the authors passed them to PriorLayer (c2c): shifted by each frame's minimum
    (``floor`` shift, their Fetch code) or negative sums clamped to 0 (clamp, their DESK code). float32 [n, C]."""
    if floor == PaperFloor.SHIFT:
        prior = scores - scores.min(axis=1, keepdims=True)
    elif floor == PaperFloor.CLAMP:
        prior = np.maximum(scores, 0.0)
    else:
        raise BadInput(f"unknown paper floor {floor!r}: expected one of {', '.join(PaperFloor)}")
    return prior.astype(np.float32)


def _log_softmax(scores: np.ndarray) -> np.ndarray:
    """log softmax over the classes (axis 1), as scipy.special.log_softmax computes it; a row without a finite
    maximum is not shifted."""
    top = scores.max(axis=1, keepdims=True)
    shifted = scores - np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return shifted - np.log(np.exp(shifted).sum(axis=1, keepdims=True))


def class_log_probs(scores: np.ndarray, mode: str, floor: PaperFloor) -> np.ndarray:
    """mode 'paper': authors' eq. 12-13 code: paper_prior + 1, normalised, log. mode 'exact': the MLN's
    own conditional distribution with classes mutually exclusive: log_softmax(scores). [n, C] float64."""
    if mode == "paper":
        smoothed = paper_prior(scores, floor).astype(np.float64) + 1.0  # +1: no zero probability
        return np.log(smoothed / smoothed.sum(axis=1, keepdims=True))
    if mode == "exact":
        return _log_softmax(scores)
    raise BadInput(f"unknown MLN mode {mode!r}: expected one of {', '.join(MODES)}")
