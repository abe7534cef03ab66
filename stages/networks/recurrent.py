"""The recurrent network type: a one-layer LSTM (gates i, f, g, o) or GRU (gates r, z, n).

Paper (Rahman et al., RO-MAN 2021): the recurrent layer reads the standardised features of each frame;
its hidden state goes to the shared head (stages/networks/prior_layer.py). The torch body is torch's own
``nn.LSTM``/``nn.GRU`` (state dict ``rnn.*``); the numpy body computes the same in float64 and agrees
with torch within 1e-5. The streaming state is the hidden state (and the LSTM's cell state).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
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


def _gates(config: Config) -> int:
    return 4 if config.cell == "lstm" else 3


def body_shapes(config: Config) -> dict[str, tuple[int, ...]]:
    """The body's arrays in the state dict and their shapes."""
    gates = _gates(config) * config.hidden_size
    return {f"{BODY}.weight_ih_l0": (gates, config.n_features), f"{BODY}.weight_hh_l0": (gates, config.hidden_size),
            f"{BODY}.bias_ih_l0": (gates,), f"{BODY}.bias_hh_l0": (gates,)}


def torch_body(config: Config) -> Any:
    """The torch module that trains it: features [B, T, F] -> (hidden [B, T, H], last state)."""
    from torch import nn

    recurrent = nn.LSTM if config.cell == "lstm" else nn.GRU
    return recurrent(config.n_features, config.hidden_size, num_layers=1, batch_first=True)


SIDE_BY_SIDE_UNITS = 160  # fitting 5 LSTMs of 32 units side by side: 1.5-1.9x; 10: slower than one at a time


def side_by_side_at_most(config: Config) -> int:
    """How many networks fit side by side at once: their block-diagonal layer grows as the square of its units."""
    return max(1, SIDE_BY_SIDE_UNITS // config.hidden_size)


def side_by_side_weights(config: Config, stacked: dict[str, Any]) -> dict[str, Any]:
    """G networks' weights (``stacked``: [G, ...] under the state dict's names) as the weights fitted side by side:
    the bodies as one layer of G·H units whose weights are block-diagonal, so each network's gates read only its own
    features and units (torch has no batched recurrent layer with separate weights), rows in the (gate, network,
    unit) order of one layer's gates. A hook zeroes the gradient off the blocks, so they stay 0; each block's
    gradient and update are those of its network's own weights. The head's weights stay stacked."""
    import torch

    g, gates, h = len(next(iter(stacked.values()))), _gates(config), config.hidden_size

    def gate_major(per_network: Any) -> Any:  # rows (network, gate, unit) -> (gate, network, unit)
        return per_network.view(g, gates, h, -1).transpose(0, 1).reshape(gates * g * h, -1)

    out = dict(stacked)
    for kind in ("ih", "hh"):
        name = f"{BODY}.weight_{kind}_l0"
        blocks = gate_major(torch.block_diag(*torch.ones_like(stacked[name])))
        out[name] = gate_major(torch.block_diag(*stacked[name])).requires_grad_()
        out[name].register_hook(lambda gradient, blocks=blocks: gradient * blocks)
        bias = f"{BODY}.bias_{kind}_l0"
        out[bias] = gate_major(stacked[bias].reshape(g, -1, 1)).view(-1).requires_grad_()
    return out


def side_by_side_stacked(config: Config, weights: dict[str, Any], g: int) -> dict[str, Any]:
    """The weights fitted side by side (:func:`side_by_side_weights`) as each network's, stacked [G, ...]."""
    gates, h = _gates(config), config.hidden_size
    out = dict(weights)
    for kind in ("ih", "hh"):
        layer = weights[f"{BODY}.weight_{kind}_l0"].view(gates, g, h, g, -1)  # [gate, network, unit, network, in]
        out[f"{BODY}.weight_{kind}_l0"] = layer.diagonal(dim1=1, dim2=3).permute(3, 0, 1, 2).reshape(g, gates * h, -1)
        bias = weights[f"{BODY}.bias_{kind}_l0"].view(gates, g, h)
        out[f"{BODY}.bias_{kind}_l0"] = bias.transpose(0, 1).reshape(g, -1)
    return out


def merged_body(config: Config, weights: list[dict[str, Any]]) -> tuple[Config, dict[str, Any]]:
    """G networks of ``config`` (their bodies' torch weights) as one layer of G·H units that computes each one's
    hidden state from the same features: the input weights stacked and the recurrent ones block-diagonal, rows in
    the (gate, network, unit) order of one layer's gates; its hidden units in the (network, unit) order."""
    import torch

    g, gates, h = len(weights), _gates(config), config.hidden_size

    def gate_major(per_network: Any) -> Any:  # rows (network, gate, unit) -> (gate, network, unit)
        return per_network.reshape(g, gates, h, -1).transpose(0, 1).reshape(gates * g * h, -1)

    out = {f"{BODY}.weight_ih_l0": gate_major(torch.cat([w[f"{BODY}.weight_ih_l0"] for w in weights])),
           f"{BODY}.weight_hh_l0": gate_major(torch.block_diag(*(w[f"{BODY}.weight_hh_l0"] for w in weights)))}
    for kind in ("ih", "hh"):
        name = f"{BODY}.bias_{kind}_l0"
        out[name] = gate_major(torch.cat([w[name] for w in weights])).reshape(-1)
    return replace(config, hidden_size=g * h), out


def torch_bodies_side_by_side(config: Config, weights: dict[str, Any], features: Any) -> Any:
    """G networks of ``config`` at once, their weights as :func:`side_by_side_weights` makes them: each network's
    features [G, B, T, F] -> hidden [G, B, T, H], each network's what its own layer computes (up to rounding)."""
    import torch

    g, b, t, _ = features.shape
    flat = tuple(weights[f"{BODY}.{name}_l0"] for name in ("weight_ih", "weight_hh", "bias_ih", "bias_hh"))
    x = features.permute(1, 2, 0, 3).reshape(b, t, -1)  # [B, T, G·F]: network-major features
    zeros = x.new_zeros(1, b, g * config.hidden_size)
    if config.cell == "lstm":
        hidden = torch.lstm(x, (zeros, zeros), flat, True, 1, 0.0, True, False, True)[0]
    else:
        hidden = torch.gru(x, zeros, flat, True, 1, 0.0, True, False, True)[0]
    return hidden.view(b, t, g, config.hidden_size).permute(2, 0, 1, 3)


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
