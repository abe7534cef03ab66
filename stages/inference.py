"""The trained networks run in numpy: recognition without torch, fast one frame at a time.

The forward pass of stages/models.py's SequenceClassifier — torch's one-layer LSTM (gates i, f, g, o) or
GRU (gates r, z, n), then h2c, the PriorLayer over [h2c, c2c] and a log-softmax — computed in float64 on
inputs standardised in float32 as training standardised them. It agrees with torch within 1e-5.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from stages import sequences

State = tuple[np.ndarray, np.ndarray] | np.ndarray  # LSTM (h, c) or GRU h, each [B, H]


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def _log_softmax(x: np.ndarray) -> np.ndarray:
    shifted = x - x.max(axis=-1, keepdims=True)
    return shifted - np.log(np.exp(shifted).sum(axis=-1, keepdims=True))


@dataclass(frozen=True)
class Network:
    """A trained network's weights and standardisation, and its configuration (``ModelConfig`` as a dict)."""

    config: dict[str, Any]
    weights: dict[str, np.ndarray]  # the torch state dict's arrays, float64
    mean: np.ndarray  # float32, as training standardised
    std: np.ndarray

    def __post_init__(self) -> None:
        w = self.weights
        # The recurrent step as one product: [x, h] @ [W_ih | W_hh]ᵀ (+ both biases; the GRU's n gate keeps
        # W_hn·h + b_hn apart, since r scales it).
        object.__setattr__(self, "_input", w["rnn.weight_ih_l0"].T.copy())
        object.__setattr__(self, "_hidden", w["rnn.weight_hh_l0"].T.copy())
        object.__setattr__(self, "_stacked", np.concatenate([w["rnn.weight_ih_l0"], w["rnn.weight_hh_l0"]], axis=1).T.copy())
        object.__setattr__(self, "_bias", w["rnn.bias_ih_l0"] + w["rnn.bias_hh_l0"])
        object.__setattr__(self, "_size", int(self.config["hidden_size"]))

    @classmethod
    def from_state(cls, config: dict[str, Any], state: Mapping[str, Any], mean: Any, std: Any) -> Network:
        weights = {name: np.asarray(value, dtype=np.float64) for name, value in state.items()}
        return cls(dict(config), weights, np.asarray(mean, dtype=np.float32), np.asarray(std, dtype=np.float32))

    @property
    def n_classes(self) -> int:
        return int(self.config["n_classes"])

    def standardise(self, features: np.ndarray) -> np.ndarray:
        return ((np.asarray(features, dtype=np.float32) - self.mean) / self.std).astype(np.float64)

    def initial_state(self, batch: int) -> State:
        zeros = np.zeros((batch, self._size))
        return (zeros, zeros.copy()) if self.config["cell"] == "lstm" else zeros

    def cell(self, x: np.ndarray, state: State) -> tuple[np.ndarray, State]:
        """One recurrent step on standardised features [B, F]: the new hidden output [B, H] and state."""
        n = self._size
        if self.config["cell"] == "lstm":
            h, c = state
            gates = np.concatenate([x, h], axis=1) @ self._stacked + self._bias
            squashed = _sigmoid(gates)  # i, f, o use it; g is tanh'd below
            c = squashed[:, n : 2 * n] * c + squashed[:, :n] * np.tanh(gates[:, 2 * n : 3 * n])
            h = squashed[:, 3 * n :] * np.tanh(c)
            return h, (h, c)
        h = state
        w = self.weights
        from_x = x @ self._input + w["rnn.bias_ih_l0"]
        from_h = h @ self._hidden + w["rnn.bias_hh_l0"]
        rz = _sigmoid(from_x[:, : 2 * n] + from_h[:, : 2 * n])
        r, z = rz[:, :n], rz[:, n:]
        h = (1.0 - z) * np.tanh(from_x[:, 2 * n :] + r * from_h[:, 2 * n :]) + z * h
        return h, h

    def head(self, hidden: np.ndarray, prior: np.ndarray | None) -> np.ndarray:
        """h2c, then the PriorLayer over [h2c, c2c] when the network has one, then log-softmax: [..., C]."""
        w = self.weights
        scores = hidden @ w["h2c.weight"].T + w["h2c.bias"]
        if "prior.weight" in w:
            if prior is None:
                raise ValueError("a PriorLayer network needs the MLN class input of every frame")
            scores = np.concatenate([scores, prior], axis=-1) @ w["prior.weight"].T + w["prior.bias"]
        return _log_softmax(scores)

    def log_probs(self, spans: list[slice], features: np.ndarray, prior: np.ndarray | None) -> np.ndarray:
        """Class log-probabilities [n, C] of every row covered by ``spans`` (raw features; each span a fresh
        sequence), spans of similar length run side by side."""
        x_all = self.standardise(features)
        out = np.zeros((len(features), self.n_classes))
        ordered = sorted(spans, key=lambda s: s.stop - s.start)
        for i in range(0, len(ordered), 256):
            batch = ordered[i : i + 256]
            x = sequences.pad(batch, x_all)
            p = None if prior is None else sequences.pad(batch, np.asarray(prior, dtype=np.float64))
            state, hidden = self.initial_state(len(batch)), np.zeros((*x.shape[:2], self._size))
            for t in range(x.shape[1]):
                hidden[:, t], state = self.cell(x[:, t], state)
            log_probs = self.head(hidden, p)
            for j, span in enumerate(batch):
                out[span] = log_probs[j, : span.stop - span.start]
        return out


class StreamingNetwork:
    """One frame in, class log-probabilities out, the recurrent state carried between frames."""

    def __init__(self, network: Network):
        self.network = network
        self.reset()

    def reset(self) -> None:
        """Start a new sequence."""
        self.state = self.network.initial_state(1)

    def step(self, features: np.ndarray, prior: np.ndarray | None = None) -> np.ndarray:
        """Class log-probabilities [C] of the next frame, given its raw features [F] (and MLN input [C])."""
        hidden, self.state = self.network.cell(self.network.standardise(features)[None], self.state)
        return self.network.head(hidden, None if prior is None else np.asarray(prior, dtype=np.float64)[None])[0]
