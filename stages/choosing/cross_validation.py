"""Cross-validation on the training split: every training frame predicted by what was fitted without its fold
(the fold's network, its MLN weights, and a network factor weight learned on the other folds), so that a
choice among methods, and the network factor's weight, are made on honest predictions and never on test.

The network factor's weight of a decoded network method is learned by the chain's exact conditional
likelihood (mlnseq.mln.cll.network_weight) on out-of-fold chains: each fold's frames under the MLN learned without
it and the network's out-of-fold log-probabilities, so that neither part has seen the frames it is weighed on (an
MLN on its own training frames is confident there, and a weight learned against it leaves the network almost
nothing: docs/choosing.md). Per fold on the other folds' chains, for the cross-validated figures; on every fold's,
for the model that decodes test.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from mlnseq.catalog.methods import decoded_name, network_of
from mlnseq.mln import chain, lag
from mlnseq.mln.chain_factors import ChainFactors
from mlnseq.fusion import decoding as decoders
from mlnseq.fusion.fuse import chain_of, fuse

if TYPE_CHECKING:
    from mlnseq.choosing.workdir_inputs import MLNInputs, WorkdirInputs

FIGURES = ("segment_accuracy", "frame_accuracy", "edit", "f1_50")  # accuracies in %


def figures_said(figures: dict[str, float], criterion: float) -> str:
    """A candidate's cross-validated figures, as conflate, export and fit say them: ``cross-validated  71.2 /  90.9 /
    83.6 (segment / frame / edit), mean  81.9`` (the mean: the criterion the choice ranks by)."""
    return (f"cross-validated {figures['segment_accuracy']:5.1f} / {figures['frame_accuracy']:5.1f} / "
            f"{figures['edit']:5.1f} (segment / frame / edit), mean {criterion:5.1f}")
# beside them: log_likelihood (nats per frame, of the true labels) and forbidden_transitions (decoded methods)


def oof_weight(chains: Sequence[ChainFactors], log_p: Sequence[np.ndarray], labels: Sequence[np.ndarray]) -> float:
    """The network factor's weight learned by exact CLL on out-of-fold chains (their per-frame log-potentials the
    MLN's of the fold's MLN, with the start distribution) and the network's out-of-fold log-probabilities there."""
    from mlnseq.mln import cll

    return cll.network_weight(ChainFactors.joined(list(chains)), np.concatenate(log_p), np.concatenate(labels))


def figures_of(predicted: np.ndarray, labels: np.ndarray, starts: np.ndarray, n_classes: int,
               segmental: bool) -> dict[str, float]:
    """Segment and frame accuracy (%), edit and F1@50 of predictions over chains cut at ``starts``."""
    from mlnseq.timeline.metrics import score_method

    scored = score_method(predicted, labels, np.cumsum(starts), n_classes, 0.5, segmental)
    return {"segment_accuracy": 100 * scored["segment_accuracy"], "frame_accuracy": 100 * scored["frame_accuracy"],
            "edit": scored.get("edit", float("nan")), "f1_50": scored.get("f1@50", float("nan"))}


@dataclass
class CrossValidated:
    figures: dict[str, dict[str, float]] = field(default_factory=dict)  # method name -> FIGURES
    fold_weights: dict[str, list[float]] = field(default_factory=dict)  # decoded network method -> per fold
    fold_frames: dict[str, list[float]] = field(default_factory=dict)  # method name -> frame accuracy (%) per fold


def cross_validate(inputs: WorkdirInputs, mln_mode: str, decodes: Sequence[str], methods: Sequence[str],
                   fixed_weight: float | None = None) -> CrossValidated:
    """Every method (with each decoding in ``decodes``) predicted on each fold by what was fitted without it;
    its figures over the whole training split. Methods whose network has no out-of-fold predictions are left out."""
    from mlnseq.mln import classifier
    from mlnseq.mln.factors import MLNFactors

    cv, data, folds = inputs.folds, inputs.data, inputs.folds.folds
    n_classes = len(inputs.classes)
    result = CrossValidated()
    usable = [m for m in methods if (network_of(m) is None or network_of(m) in cv.log_probs)
              and (network_of(m) == m or cv.mln)]
    predicted = {decoded_name(m, d): np.zeros(len(data.labels), dtype=np.int64) for m in usable for d in decodes}
    likelihood = {name: np.zeros(len(data.labels)) for name in predicted}  # log p(true label) per frame
    forbidden = dict.fromkeys((name for name in predicted if "+" in name), 0)
    decoded = [d for d in decodes if d != "none"]
    held_out: dict[str, list[tuple[np.ndarray, ChainFactors]]] = {}  # method -> each fold's rows and chain (weight 0)
    for k, fold in enumerate(folds.masks()):
        rows, starts = fold.rows, fold.starts(data.episodes)
        fold_mln: MLNInputs | None = cv.mln[k] if cv.mln else None
        p_mln = None if fold_mln is None else np.exp(classifier.class_log_probs(fold_mln.scores, mln_mode,
                                                                                  inputs.paper_floor))
        factors = None
        if fold_mln is not None and any(d != "none" for d in decodes):
            factors = MLNFactors.from_weights(fold_mln.weights, fold_mln.columns, inputs.classes)
        start = fold.start(data.labels, data.episodes, n_classes)
        truth = data.labels[rows]
        for method in usable:
            network = network_of(method)
            log_p = cv.log_probs.get(network)
            if "none" in decodes:
                probabilities = fuse(method, None if log_p is None else np.exp(log_p[rows]),
                                     None if p_mln is None else p_mln[rows])
                name = decoded_name(method, "none")
                predicted[name][rows] = probabilities.argmax(1)
                likelihood[name][rows] = _log_likelihoods(probabilities, truth)
            if decoded:
                held_out.setdefault(method, []).append((rows, chain_of(method, factors, fold_mln.evidence[rows], starts,
                                                                       None if log_p is None else log_p[rows], 0.0,
                                                                       start)))
    for method in held_out if decoded else ():
        held_out[method] = weighted(held_out[method], cv.log_probs.get(network_of(method)), data.labels, fixed_weight,
                                    [result.fold_weights.setdefault(decoded_name(method, d), []) for d in decoded])
    _decode_held_out(held_out, decoded, data.labels, predicted, likelihood, forbidden)
    rows = np.flatnonzero(folds.fold >= 0)
    starts = chain.chain_starts(data.episodes, folds.fold, rows=rows)
    scored: dict[tuple[bytes, bool], dict[str, float]] = {}  # methods predicting alike (decoders often agree): once
    held_by_fold = [fold.held for fold in folds.masks()]
    for name, values in predicted.items():
        network = network_of(name.partition("+")[0])
        key = (values[rows].tobytes(), network is None or inputs.networks[network].checkpoint.mode != "segment")
        if key not in scored:
            scored[key] = figures_of(values[rows], data.labels[rows], starts, n_classes, segmental=key[1])
        result.figures[name] = {**scored[key], "log_likelihood": float(likelihood[name][rows].mean())}
        result.fold_frames[name] = [100 * float((values[held] == data.labels[held]).mean()) for held in held_by_fold]
        if name in forbidden:
            result.figures[name]["forbidden_transitions"] = forbidden[name]
    return result


def weighted(parts: list[tuple[np.ndarray, ChainFactors]], log_p: np.ndarray | None, labels: np.ndarray,
             fixed: float | list[float] | None, said: list[list[float]]) -> list[tuple[np.ndarray, ChainFactors]]:
    """Each fold's chain with the network's log-probabilities at the weight learned on the other folds' chains (or
    ``fixed``: one for every fold, or each fold's as learned before), each weight appended to every list of
    ``said``; the MLN alone (no network) as it is."""
    if log_p is None:
        return parts
    out = []
    for k, (rows, base) in enumerate(parts):
        others = [j for j in range(len(parts)) if j != k]
        known = fixed[k] if isinstance(fixed, list) else fixed
        weight = known if known is not None else oof_weight([parts[j][1] for j in others],
                                                            [log_p[parts[j][0]] for j in others],
                                                            [labels[parts[j][0]] for j in others])
        for weights in said:
            weights.append(weight)
        out.append((rows, replace(base, unary=base.unary + weight * log_p[rows])))
    return out


def _decode_held_out(held_out: dict[str, list[tuple[np.ndarray, ChainFactors]]], decodes: list[str],
                     labels: np.ndarray, predicted: dict, likelihood: dict, forbidden: dict) -> None:
    """Decode every method's held-out chains of every fold at once (the decoders' passes shared), and fill in their
    classes, log-likelihoods of the true labels and forbidden transitions per decoding."""
    methods = list(held_out)
    joined = [ChainFactors.joined([chained for _, chained in held_out[m]]) for m in methods]
    for method, chained, outs in zip(methods, joined, decoders.decode_each(joined, decodes)):
        rows = np.concatenate([part_rows for part_rows, _ in held_out[method]])
        for decode, out in zip(decodes, outs):
            name = decoded_name(method, decode)
            predicted[name][rows] = out.path
            likelihood[name][rows] = _log_likelihoods(out.probabilities, labels[rows])
            forbidden[name] += lag.forbidden_transitions(chained, out.path)


def _log_likelihoods(probabilities: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """log p(true label) per frame, floored (decoding.LIKELIHOOD_FLOOR), probabilities renormalised per frame."""
    probabilities = np.asarray(probabilities, dtype=np.float64)
    total = probabilities.sum(axis=1)
    picked = probabilities[np.arange(len(labels)), labels] / np.where(total > 0, total, 1.0)
    return np.log(np.maximum(picked, decoders.LIKELIHOOD_FLOOR))


def test_weight(method: str, inputs: WorkdirInputs) -> float:
    """The weight that decodes test: learned on every fold's out-of-fold chain (the fold's MLN and the network's
    out-of-fold log-probabilities on the fold's frames)."""
    from mlnseq.mln.factors import MLNFactors

    cv, data, folds = inputs.folds, inputs.data, inputs.folds.folds
    log_p = cv.log_probs[network_of(method)]
    parts, network = [], []
    for fold, fold_mln in zip(folds.masks(), cv.mln):
        rows = fold.rows
        factors = MLNFactors.from_weights(fold_mln.weights, fold_mln.columns, inputs.classes)
        start = fold.start(data.labels, data.episodes, len(inputs.classes))
        parts.append(chain_of(method, factors, fold_mln.evidence[rows], fold.starts(data.episodes), log_p[rows], 0.0,
                              start))
        network.append(rows)
    return oof_weight(parts, [log_p[rows] for rows in network], [data.labels[rows] for rows in network])

