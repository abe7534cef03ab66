"""The recurrent network type: a one-layer LSTM (gates i, f, g, o) or GRU (gates r, z, n).

Paper (Rahman et al., RO-MAN 2021): the recurrent layer reads the standardised features of each frame;
its hidden state goes to the shared head (stages/networks/prior_layer.py). The torch body is torch's own
``nn.LSTM``/``nn.GRU`` (state dict ``rnn.*``); the numpy body computes the same in float64 and agrees
with torch within 1e-5. The streaming state is the hidden state (and the LSTM's cell state).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

BODY = "rnn"  # the body's name in the state dict
State = tuple[np.ndarray, np.ndarray] | np.ndarray  # LSTM (h, c) or GRU h, each [B, H]


@dataclass(frozen=True)
class Config:
    """The shape of a recurrent network; stored in every checkpoint."""

    n_features: int
    n_classes: int
    hidden_size: int = 32
    cell: str = "lstm"  # lstm | gru
    prior_layer: bool = False

    def to_dict(self) -> dict:
        return asdict(self)


def describe(config: Config) -> str:
    return f"{config.cell} of {config.hidden_size}"


def body_shapes(config: Config) -> dict[str, tuple[int, ...]]:
    """The body's arrays in the state dict and their shapes."""
    gates = (4 if config.cell == "lstm" else 3) * config.hidden_size
    return {f"{BODY}.weight_ih_l0": (gates, config.n_features), f"{BODY}.weight_hh_l0": (gates, config.hidden_size),
            f"{BODY}.bias_ih_l0": (gates,), f"{BODY}.bias_hh_l0": (gates,)}


def torch_body(config: Config) -> Any:
    """The torch module that trains it: features [B, T, F] -> (hidden [B, T, H], last state)."""
    from torch import nn

    recurrent = nn.LSTM if config.cell == "lstm" else nn.GRU
    return recurrent(config.n_features, config.hidden_size, num_layers=1, batch_first=True)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * x))


class NumpyBody:
    """The trained body in numpy: one step, or whole padded sequences."""

    def __init__(self, config: dict[str, Any], weights: dict[str, np.ndarray]):
        self.lstm = config["cell"] == "lstm"
        self.size = int(config["hidden_size"])
        w_ih, w_hh = weights[f"{BODY}.weight_ih_l0"], weights[f"{BODY}.weight_hh_l0"]
        self.b_ih, self.b_hh = weights[f"{BODY}.bias_ih_l0"], weights[f"{BODY}.bias_hh_l0"]
        # The recurrent step as one product: [x, h] @ [W_ih | W_hh]ᵀ (+ both biases; the GRU's n gate keeps
        # W_hn·h + b_hn apart, since r scales it).
        self._input, self._hidden = w_ih.T.copy(), w_hh.T.copy()
        self._stacked = np.concatenate([w_ih, w_hh], axis=1).T.copy()
        self._bias = self.b_ih + self.b_hh

    def initial_state(self, batch: int) -> State:
        zeros = np.zeros((batch, self.size))
        return (zeros, zeros.copy()) if self.lstm else zeros

    def step(self, x: np.ndarray, state: State) -> tuple[np.ndarray, State]:
        """One step on standardised features [B, F]: the new hidden output [B, H] and state."""
        n = self.size
        if self.lstm:
            h, c = state
            gates = np.concatenate([x, h], axis=1) @ self._stacked + self._bias
            squashed = _sigmoid(gates)  # i, f, o use it; g is tanh'd below
            c = squashed[:, n : 2 * n] * c + squashed[:, :n] * np.tanh(gates[:, 2 * n : 3 * n])
            h = squashed[:, 3 * n :] * np.tanh(c)
            return h, (h, c)
        h = state
        from_x = x @ self._input + self.b_ih
        from_h = h @ self._hidden + self.b_hh
        rz = _sigmoid(from_x[:, : 2 * n] + from_h[:, : 2 * n])
        r, z = rz[:, :n], rz[:, n:]
        h = (1.0 - z) * np.tanh(from_x[:, 2 * n :] + r * from_h[:, 2 * n :]) + z * h
        return h, h

    def sequence(self, x: np.ndarray) -> np.ndarray:
        """Hidden outputs [B, T, H] of padded sequences [B, T, F], each from a fresh state."""
        state, hidden = self.initial_state(len(x)), np.zeros((*x.shape[:2], self.size))
        for t in range(x.shape[1]):
            hidden[:, t], state = self.step(x[:, t], state)
        return hidden
