"""The network factor's weight of a decoded method: how much the network's log-probabilities count against
the MLN's factors in the chain. The one place that decides it (:class:`WeightDecision`, for conflate and export):
given by option; else learned on out-of-fold predictions (networks trained with folds); else chosen on a
network's validation part (never on test); else 1."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from mlnseq.catalog import artifacts
from mlnseq.mln import chain
from mlnseq.catalog.methods import Method, WeightSource, network_of
from mlnseq.catalog.notes import UNIFORM_TRANSITIONS, WEIGHT_NOT_CHOSEN, Note
from mlnseq.catalog.parts import Part
from mlnseq.fusion.decoding import decode
from mlnseq.fusion.fuse import chain_of

if TYPE_CHECKING:
    from mlnseq.mln.factors import MLNFactors
    from mlnseq.choosing.workdir_inputs import WorkdirInputs

NETWORK_WEIGHTS = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)  # the network factor's weights tried on validation


@dataclass(frozen=True)
class WeightChoice:
    """The network factor's weight of a decoded method, how it was set, and the validation frame accuracy."""

    weight: float
    accuracy: float | None  # None: not chosen on a validation part
    tried: dict[float, float] = field(default_factory=dict)
    how: WeightSource = WeightSource.VALIDATION

    def record(self) -> dict[str, Any]:
        return {"weight": self.weight, "how": str(self.how), "validation_frame_accuracy": self.accuracy,
                "tried": {str(w): a for w, a in self.tried.items()}}


def choose_on_validation(method: str, kind: str, mln: MLNFactors, evidence: np.ndarray, episodes: np.ndarray,
                         parts: np.ndarray, log_p_network: np.ndarray, labels: np.ndarray) -> WeightChoice:
    """The weight in NETWORK_WEIGHTS with the best frame accuracy on the rows ``parts`` marks val, never test (ties:
    the one nearest 1), their chains cut where validation resumes too; with no validation row the weight is 1."""
    validation = parts == Part.VAL
    if not validation.any():
        return WeightChoice(1.0, None, {}, WeightSource.FIXED)
    starts = chain.chain_starts(episodes, parts, rows=validation)
    tried = {}
    for weight in NETWORK_WEIGHTS:
        factors = chain_of(method, mln, evidence[validation], starts, log_p_network[validation], weight)
        tried[weight] = float((decode(factors, kind).path == labels[validation]).mean())
    best = max(tried, key=lambda w: (tried[w], -abs(np.log(w))))
    return WeightChoice(best, tried[best], tried)


def choose(method: str, kind: str, mln: MLNFactors, evidence: np.ndarray, episodes: np.ndarray, parts: np.ndarray,
           log_p_network: np.ndarray, labels: np.ndarray, fixed: float | None = None) -> WeightChoice:
    """A decoded network method's weight: ``fixed`` when given, else chosen on the rows ``parts`` marks val."""
    if fixed is not None:
        return WeightChoice(fixed, None, {}, WeightSource.FIXED)
    return choose_on_validation(method, kind, mln, evidence, episodes, parts, log_p_network, labels)


def decoding_notes(temporal: bool, unvalidated: list[str]) -> list[Note]:
    """What decoding says: uniform transitions (no temporal formula), and the networks whose decoded methods keep
    the weight 1 because they were trained without a validation part."""
    notes = []
    if not temporal:
        notes.append(Note(UNIFORM_TRANSITIONS, f"{artifacts.WEIGHTS} has no temporal formula (Next): decoding uses "
                                               "uniform transitions"))
    if unvalidated:
        notes.append(Note(WEIGHT_NOT_CHOSEN, f"{', '.join(unvalidated)} trained without a validation part "
                                             "(`train --select last` or `val_accuracy`): its decoded methods keep the "
                                             "network factor's weight 1"))
    return notes


@dataclass
class WeightDecision:
    """Decides the network factor's weight of a workdir's decoded network methods, for conflate (every method) and
    export (one): ``fixed`` when given; else learned by CLL on the out-of-fold predictions of a network trained
    with folds (once per method: every decoding shares it); else chosen on the network's validation part."""

    inputs: WorkdirInputs
    mln: MLNFactors
    fixed: float | None = None
    learned: dict[Method, float] = field(default_factory=dict)

    def folded(self, network: Method) -> bool:
        return self.inputs.folds is not None and network in self.inputs.folds.log_probs

    def choice(self, method: Method, kind: str) -> WeightChoice:
        """The weight of ``method`` (a network method) decoded by ``kind``, and how it was set."""
        from mlnseq.choosing.cross_validation import test_weight

        network = network_of(method)
        if self.fixed is not None:
            return WeightChoice(self.fixed, None, {}, WeightSource.FIXED)
        if self.folded(network):
            if method not in self.learned:
                self.learned[method] = test_weight(method, self.inputs)
            return WeightChoice(self.learned[method], None, {}, WeightSource.LEARNED)
        trained, data = self.inputs.networks[network], self.inputs.data
        return choose(method, kind, self.mln, self.inputs.mln.evidence, data.episodes, trained.parts,
                      trained.log_probs, data.labels)

    def notes(self, networks: list[Method]) -> list[Note]:
        """What decoding ``networks``' methods says (:func:`decoding_notes`): the networks among them whose weight
        stays 1 as they have neither out-of-fold predictions nor a validation part."""
        unvalidated = [] if self.fixed is not None else sorted(
            n for n in networks
            if not self.folded(n) and not self.inputs.networks[n].checkpoint.config.get("val_spans"))
        return decoding_notes(self.mln.temporal, unvalidated)
