"""A trained network in numpy: recognition without torch, fast one frame at a time.

The forward pass of stages/networks/classifier.py's SequenceClassifier — the type's numpy body, then the
shared head — computed in float64 on inputs standardised in float32 as training standardised them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from mlnseq import networks
from mlnseq.timeline import sequences
from mlnseq.networks.prior_layer import head


@dataclass(frozen=True)
class Network:
    """A trained network's weights and standardisation, and its configuration (the type's ``Config`` as a dict)."""

    config: dict[str, Any]
    weights: dict[str, np.ndarray]  # the torch state dict's arrays, float64
    mean: np.ndarray  # float32, as training standardised
    std: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "body", networks.module_of(self.config["cell"]).NumpyBody(self.config, self.weights))

    @classmethod
    def from_state(cls, config: dict[str, Any], state: Mapping[str, Any], mean: Any, std: Any) -> Network:
        weights = {name: np.asarray(value, dtype=np.float64) for name, value in state.items()}
        return cls(dict(config), weights, np.asarray(mean, dtype=np.float32), np.asarray(std, dtype=np.float32))

    @property
    def n_classes(self) -> int:
        return int(self.config["n_classes"])

    def standardise(self, features: np.ndarray) -> np.ndarray:
        return ((np.asarray(features, dtype=np.float32) - self.mean) / self.std).astype(np.float64)

    def head(self, hidden: np.ndarray, prior: np.ndarray | None) -> np.ndarray:
        return head(self.weights, hidden, prior)

    def log_probs(self, spans: list[slice], features: np.ndarray, prior: np.ndarray | None) -> np.ndarray:
        """Class log-probabilities [n, C] of every row covered by ``spans`` (raw features; each span a fresh
        sequence), spans of similar length run side by side."""
        x_all = self.standardise(features)
        out = np.zeros((len(features), self.n_classes))
        ordered = sorted(spans, key=lambda s: s.stop - s.start)
        for i in range(0, len(ordered), networks.INFERENCE_BATCH):
            batch = ordered[i : i + networks.INFERENCE_BATCH]
            x = sequences.pad(batch, x_all)
            p = None if prior is None else sequences.pad(batch, np.asarray(prior, dtype=np.float64))
            log_probs = self.head(self.body.sequence(x), p)
            for j, span in enumerate(batch):
                out[span] = log_probs[j, : span.stop - span.start]
        return out


class StreamingNetwork:
    """One frame in, class log-probabilities out, the body's streaming state carried between frames."""

    def __init__(self, network: Network):
        self.network = network
        self.reset()

    def reset(self) -> None:
        """Start a new sequence."""
        self.state = self.network.body.initial_state(1)

    def step(self, features: np.ndarray, prior: np.ndarray | None = None) -> np.ndarray:
        """Class log-probabilities [C] of the next frame, given its raw features [F] (and MLN input [C])."""
        hidden, self.state = self.network.body.step(self.network.standardise(features)[None], self.state)
        return self.network.head(hidden, None if prior is None else np.asarray(prior, dtype=np.float64)[None])[0]
