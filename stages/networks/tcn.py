"""The causal TCN network type: dilated causal 1-D convolutions with residual connections.

After MS-TCN's single stage (Farha & Gall, CVPR 2019), made causal so that it can stream: a 1x1
convolution maps the features to ``hidden_size`` channels, then ``levels`` dilated residual layers
with dilation 2^l (eq. 1-2: Ĥ_l = ReLU(W_1 ∗ H_{l-1} + b_1), H_l = H_{l-1} + W_2 ∗ Ĥ_l + b_2, W_1 a
kernel of ``kernel_size`` taps, W_2 1x1), each padded on the left only, so frame t sees frames
t - r + 1 .. t, r = 1 + (kernel_size - 1)(2^levels - 1) the receptive field. H_L goes to the shared
head. Optional: MS-TCN's truncated-MSE smoothing loss (eq. 4) with weight ``smoothing`` (MS-TCN: 0.15).

The numpy body's streaming state is a ring buffer per layer holding the last (kernel_size - 1)·2^l + 1
inputs of that layer, so a frame costs the same at any point of a stream.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from functools import cache
from typing import Any

import numpy as np

BODY = "tcn"  # the body's name in the state dict
TAU = 4.0  # MS-TCN's truncation of the log-probability change between frames


@dataclass(frozen=True)
class Config:
    """The shape of a causal TCN (and its smoothing loss's weight); stored in every checkpoint."""

    n_features: int
    n_classes: int
    hidden_size: int = 32  # channels of every layer
    cell: str = "tcn"
    prior_layer: bool = False
    kernel_size: int = 3
    levels: int = 5
    smoothing: float = 0.0  # weight of the truncated-MSE smoothing loss; 0: NLL only

    def to_dict(self) -> dict:
        return asdict(self)


def receptive_field(kernel_size: int, levels: int) -> int:
    return 1 + (kernel_size - 1) * (2**levels - 1)


def describe(config: Config) -> str:
    field = receptive_field(config.kernel_size, config.levels)
    return (f"tcn of {config.hidden_size} channels, kernel {config.kernel_size}, {config.levels} levels "
            f"(receptive field {field} frames)" + (f", smoothing {config.smoothing:g}" if config.smoothing else ""))


def body_shapes(config: Config) -> dict[str, tuple[int, ...]]:
    """The body's arrays in the state dict and their shapes."""
    h, k = config.hidden_size, config.kernel_size
    shapes = {f"{BODY}.conv_in.weight": (h, config.n_features, 1), f"{BODY}.conv_in.bias": (h,)}
    for level in range(config.levels):
        shapes |= {f"{BODY}.dilated.{level}.weight": (h, h, k), f"{BODY}.dilated.{level}.bias": (h,),
                   f"{BODY}.pointwise.{level}.weight": (h, h, 1), f"{BODY}.pointwise.{level}.bias": (h,)}
    return shapes


def torch_body(config: Config) -> Any:
    """The torch module that trains it: features [B, T, F] -> (hidden [B, T, H], None)."""
    return _torch_tcn()(config)


@cache
def _torch_tcn() -> type:
    import torch
    from torch import nn

    class CausalTCN(nn.Module):
        def __init__(self, config: Config):
            super().__init__()
            h, k = config.hidden_size, config.kernel_size
            self.pads = [(k - 1) * 2**level for level in range(config.levels)]
            self.conv_in = nn.Conv1d(config.n_features, h, 1)
            self.dilated = nn.ModuleList(nn.Conv1d(h, h, k, dilation=2**level) for level in range(config.levels))
            self.pointwise = nn.ModuleList(nn.Conv1d(h, h, 1) for _ in range(config.levels))

        def forward(self, features: torch.Tensor, state: Any = None) -> tuple[torch.Tensor, None]:
            if state is not None:
                raise ValueError("the torch TCN runs whole sequences; stream with the numpy body")
            x = self.conv_in(features.transpose(1, 2))  # [B, H, T]
            for pad, dilated, pointwise in zip(self.pads, self.dilated, self.pointwise):
                x = x + pointwise(torch.relu(dilated(nn.functional.pad(x, (pad, 0)))))  # eq. 1-2, causal
            return x.transpose(1, 2), None

    return CausalTCN


def auxiliary_loss(config: Config, log_probs: Any, valid: Any, weight: Any = None) -> Any:
    """MS-TCN eq. 4: the mean over frames and classes of min(Δ², τ²), Δ the change of the log-probability
    from the previous frame (held fixed), averaged within each sequence, times ``smoothing``; None when 0.
    ``log_probs`` [..., B, T, C]; the sequences' mean, or with ``weight`` [..., B] their weighted sum."""
    if not config.smoothing:
        return None
    delta = log_probs[..., 1:, :] - log_probs[..., :-1, :].detach()
    pairs = (valid[..., 1:] & valid[..., :-1]).to(log_probs.dtype)
    truncated = delta.pow(2).clamp(max=TAU**2).mean(-1)  # [..., B, T-1]
    per_sequence = (truncated * pairs).sum(-1) / pairs.sum(-1).clamp(min=1)
    return config.smoothing * (per_sequence.mean() if weight is None else (per_sequence * weight).sum())


def torch_bodies_side_by_side(config: Config, params: dict[str, Any], features: Any) -> Any:
    """G networks of ``config`` at once as batched matrix products, which one core runs about twice as fast as G
    convolutions: their weights stacked (``params``, [G, ...] under the state dict's names) and each network's
    features [G, B, T, F] -> hidden [G, B, T, H], each network's the one its CausalTCN computes (up to rounding)."""
    import torch

    from mlnseq.networks.classifier import affine

    g, b, t, _ = features.shape
    h, k = config.hidden_size, config.kernel_size
    x = affine(features.reshape(g, b * t, -1), params[f"{BODY}.conv_in.weight"][..., 0],
               params[f"{BODY}.conv_in.bias"])
    for level in range(config.levels):
        d, dilated, pointwise = 2**level, f"{BODY}.dilated.{level}", f"{BODY}.pointwise.{level}"
        padded = torch.nn.functional.pad(x.view(g, b, t, h), (0, 0, (k - 1) * d, 0))  # causal: zeros before frame 0
        taps = torch.cat([padded[:, :, m * d : m * d + t] for m in range(k)], -1).view(g, b * t, k * h)
        kernel = params[f"{dilated}.weight"].permute(0, 1, 3, 2).reshape(g, h, k * h)  # [G, out, tap-major in]
        inner = torch.relu(affine(taps, kernel, params[f"{dilated}.bias"]))
        x = x + affine(inner, params[f"{pointwise}.weight"][..., 0], params[f"{pointwise}.bias"])
    return x.view(g, b, t, h)


def merged_body(config: Config, weights: list[dict[str, Any]]) -> tuple[Config, dict[str, Any]]:
    """G networks of ``config`` (their bodies' torch weights) as one TCN of G·H channels that computes each one's
    channels from the same features: the input convolutions stacked, the others block-diagonal (each network's
    channels read only its own), channels in the (network, channel) order."""
    import torch

    def blocks(name: str) -> Any:  # [G·H, G·H, k]: each network's kernel on the diagonal
        return torch.stack([torch.block_diag(*(w[name][..., m] for w in weights))
                            for m in range(weights[0][name].shape[-1])], -1)

    out = {f"{BODY}.conv_in.weight": torch.cat([w[f"{BODY}.conv_in.weight"] for w in weights]),
           f"{BODY}.conv_in.bias": torch.cat([w[f"{BODY}.conv_in.bias"] for w in weights])}
    for level in range(config.levels):
        for layer in (f"{BODY}.dilated.{level}", f"{BODY}.pointwise.{level}"):
            out[f"{layer}.weight"] = blocks(f"{layer}.weight")
            out[f"{layer}.bias"] = torch.cat([w[f"{layer}.bias"] for w in weights])
    return replace(config, hidden_size=len(weights) * config.hidden_size), out


class Ring:
    """The streaming state: one ring buffer [B, span, H] per layer, and the frames seen."""

    def __init__(self, batch: int, spans: list[int], size: int):
        self.buffers = [np.zeros((batch, span, size)) for span in spans]
        self.t = 0


class NumpyBody:
    """The trained body in numpy: one step from the ring buffers, or whole padded sequences."""

    def __init__(self, config: dict[str, Any], weights: dict[str, np.ndarray]):
        self.size, k = int(config["hidden_size"]), int(config["kernel_size"])
        levels = int(config["levels"])
        self.dilations = [2**level for level in range(levels)]
        self.spans = [(k - 1) * d + 1 for d in self.dilations]
        self.w_in = weights[f"{BODY}.conv_in.weight"][:, :, 0].T.copy()  # [F, H]
        self.b_in = weights[f"{BODY}.conv_in.bias"]
        # tap m of a dilated kernel reads the input (k - 1 - m)·d frames back
        self.taps = [weights[f"{BODY}.dilated.{level}.weight"] for level in range(levels)]  # [H, H, k]
        self.stacked = [w.transpose(2, 1, 0).reshape(k * self.size, self.size).copy() for w in self.taps]
        self.b_dilated = [weights[f"{BODY}.dilated.{level}.bias"] for level in range(levels)]
        self.w_point = [weights[f"{BODY}.pointwise.{level}.weight"][:, :, 0].T.copy() for level in range(levels)]
        self.b_point = [weights[f"{BODY}.pointwise.{level}.bias"] for level in range(levels)]
        self.back = [(k - 1 - np.arange(k)) * d for d in self.dilations]

    def initial_state(self, batch: int) -> Ring:
        return Ring(batch, self.spans, self.size)

    def step(self, x: np.ndarray, state: Ring) -> tuple[np.ndarray, Ring]:
        """One frame of standardised features [B, F]: the hidden output [B, H]; the ring buffers advance."""
        h = x @ self.w_in + self.b_in
        for level, buffer in enumerate(state.buffers):
            span = self.spans[level]
            buffer[:, state.t % span] = h
            window = buffer[:, (state.t - self.back[level]) % span].reshape(len(h), -1)  # frames before 0 are 0
            inner = np.maximum(window @ self.stacked[level] + self.b_dilated[level], 0.0)
            h = h + inner @ self.w_point[level] + self.b_point[level]
        state.t += 1
        return h, state

    def sequence(self, x: np.ndarray) -> np.ndarray:
        """Hidden outputs [B, T, H] of padded sequences [B, T, F], each from zeros before its first frame."""
        h = x @ self.w_in + self.b_in
        n = h.shape[1]
        for level, d in enumerate(self.dilations):
            padded = np.concatenate([np.zeros((len(h), self.spans[level] - 1, self.size)), h], axis=1)
            inner = sum(padded[:, m * d : m * d + n] @ self.taps[level][:, :, m].T
                        for m in range(self.taps[level].shape[2]))
            h = h + np.maximum(inner + self.b_dilated[level], 0.0) @ self.w_point[level] + self.b_point[level]
        return h
