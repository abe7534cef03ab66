"""The terms of an undecoded frame's margin, log P(a) - log P(b), by the rescale rule (stages/explaining/explainer.py
says why it is exact): the network alone; the MLN's formulas, each its share of the score difference; eq. 16, the
network's and the MLN's shares of the log-odds difference it adds up."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mlnseq.catalog.methods import NETWORKS, Method
from mlnseq.explaining.explainer import TINY, Explainer, Gathered, Scores
from mlnseq.explaining.terms import Term, TermKind


def _logit(p: np.ndarray, epsilon: float) -> np.ndarray:
    """log-odds of probabilities clipped as eq. 16 clips them (at ``epsilon``)."""
    clipped = np.clip(np.asarray(p, dtype=np.float64), epsilon, 1 - epsilon)
    return np.log(clipped) - np.log1p(-clipped)


def undecoded(explainer: Explainer, scores: Scores, t: int, versus: int | None):
    """(chosen, versus, margin, terms) of frame ``t`` of an undecoded method."""
    scoring, probabilities = explainer.scoring, scores.probabilities[t]
    chosen = int(scores.path[t])
    if versus is None:
        others = np.where(np.arange(len(probabilities)) == chosen, -np.inf, probabilities)
        versus = int(np.argmax(others))
    gathered = Gathered()
    a, b = chosen, versus
    if scoring.method in NETWORKS:
        log_p = scores.log_p_network[t]
        margin = float(log_p[a] - log_p[b])
        gathered.terms.append(Term(TermKind.NETWORK, f"network ({scoring.network}): log p {log_p[a]:.2f} vs "
                                   f"{log_p[b]:.2f}", margin, weight=1.0))
        return chosen, versus, margin, gathered
    log_mln = scores.log_p_mln[t]
    mln_margin = float(log_mln[a] - log_mln[b])
    if scoring.method == Method.MLN:
        formula_terms(explainer, scores, t, a, b, mln_margin, gathered)
        return chosen, versus, mln_margin, gathered
    network, mln = np.exp(scores.log_p_network[t]), np.exp(log_mln)
    with np.errstate(divide="ignore"):
        margin = float(np.log(probabilities[a]) - np.log(probabilities[b]))
    logit = lambda p: _logit(p, scoring.epsilon)  # noqa: E731
    odds_network, odds_mln = float(logit(network[a]) - logit(network[b])), float(logit(mln[a]) - logit(mln[b]))
    odds = odds_network + odds_mln
    ratio = margin / odds if abs(odds) > TINY else 0.0
    gathered.terms.append(Term(TermKind.NETWORK, f"network ({scoring.network}): log-odds {logit(network[a]):.2f} vs "
                               f"{logit(network[b]):.2f} (its share under eq. 16)", odds_network * ratio, weight=1.0))
    formula_terms(explainer, scores, t, a, b, odds_mln * ratio, gathered)
    return chosen, versus, margin, gathered


def formula_terms(explainer: Explainer, scores: Scores, t: int, a: int, b: int, share: float,
                  gathered: Gathered) -> None:
    """The per-frame formulas' shares of ``share``, each by its share of the MLN's score difference (its weight x
    its truth difference; a hard formula counted with the classifier's weight for it)."""
    key = (explainer.frame_key(scores.evidence[t]), a, b)
    if key not in explainer.shares:
        truths = explainer.frame_truths(scores.evidence[t])
        differences = explainer.classifier_weights * (truths.true[a] - truths.true[b])
        explainer.shares[key] = (float(differences.sum()), [
            (explainer.formula_term(explainer.per_frame[j], 0.0, (int(truths.true[a, j]), int(truths.true[b, j])),
                                    float(explainer.classifier_weights[j])), float(differences[j]))
            for j in np.flatnonzero(differences).tolist()])
    total, terms = explainer.shares[key]
    if abs(total) <= TINY:
        if share:
            gathered.notes.append("the formulas do not tell the two classes apart")
        return
    gathered.terms += [replace(term, contribution=difference * share / total) for term, difference in terms]
