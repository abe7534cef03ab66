"""The MLN classifier: per-frame class scores from learned weights, and the authors' use of them.

A frame's score for class k is the MLN's log-potential with Topic(C<k>) true and the other Topic
atoms false, minus that with every Topic atom false; for `body => Topic(C<k>)` this adds the
weight to class k exactly when the body holds. Hard formulas count with ``HARD_WEIGHT``.
"""

from __future__ import annotations

import numpy as np
import polars as pl
from scipy.special import log_softmax

from stages import artifacts
from stages.errors import BadInput
from stages.mln.grounding import CLASS, AtomSpace, atom_matrix, class_constant, ground, truth
from stages.mln.syntax import MLNSyntaxError, atoms, parse_formula

HARD_WEIGHT = 1000.0  # a hard formula's weight in the scores: far above any learned weight
MODES = ("paper", "exact")


def class_scores(predicates: pl.DataFrame, weights: pl.DataFrame, n_classes: int) -> np.ndarray:
    """[n_frames, n_classes] float64: per frame, sum of the weights of the formulas whose body (the
    evidence part) is true in that frame and whose head is Topic(C<k>) — i.e. the formulas that are
    satisfied only if the class is k. Row order = predicates' row order."""
    words = tuple(artifacts.feature_columns(predicates))
    space = AtomSpace(words, tuple(class_constant(k) for k in range(n_classes)))
    evidence = predicates.select(words).to_numpy().astype(bool) if words else np.zeros((predicates.height, 0), bool)
    unique, inverse = np.unique(evidence, axis=0, return_inverse=True)
    no_class = atom_matrix(unique, None, n_classes)
    scores = np.zeros((len(unique), n_classes))
    for text, weight, hard in weights.select("formula", "weight", "hard").iter_rows():
        if weight == 0.0 and not hard:
            continue
        weight = HARD_WEIGHT if hard else weight
        try:
            formula = parse_formula(text, "weights.parquet")
        except MLNSyntaxError as error:
            raise BadInput(f"{error}; rerun `mlnseq learn-weights`") from error
        for atom in atoms(formula):
            if not space.contains(atom):
                raise BadInput(f"weights.parquet formula {text} uses {atom.args[0]}, which predicates.parquet lacks")
        for grounding in ground(formula, space):
            baseline = truth(grounding, no_class, space)
            if not any(a.predicate == CLASS for a in atoms(grounding)):
                continue
            for k in range(n_classes):
                with_class = no_class.copy()
                with_class[:, len(words) + k] = True
                scores[:, k] += weight * (truth(grounding, with_class, space).astype(float) - baseline)
    return scores[inverse.reshape(-1)]


def paper_prior(scores: np.ndarray, source: str) -> np.ndarray:
    """The class weights as the authors passed them to PriorLayer (c2c): Fetch: shifted by the minimum;
    DESK, and any other source such as a user's table: negative sums clamped to 0. float32 [n, C]."""
    if source == "fetch":
        prior = scores - scores.min(axis=1, keepdims=True)
    else:
        prior = np.maximum(scores, 0.0)
    return prior.astype(np.float32)


def class_log_probs(scores: np.ndarray, mode: str, source: str) -> np.ndarray:
    """mode 'paper': authors' eq. 12-13 code: paper_prior + 1, normalised, log. mode 'exact': the MLN's
    own conditional distribution with classes mutually exclusive: log_softmax(scores). [n, C] float64."""
    if mode == "paper":
        smoothed = paper_prior(scores, source).astype(np.float64) + 1.0  # +1: no zero probability
        return np.log(smoothed / smoothed.sum(axis=1, keepdims=True))
    if mode == "exact":
        return log_softmax(scores, axis=1)
    raise BadInput(f"unknown MLN mode {mode!r}: expected one of {', '.join(MODES)}")
