"""The torch network that training fits: a type's body -> h2c -> (PriorLayer) -> log-softmax.

The body comes from the registry (stages/networks/); h2c and the PriorLayer are the shared head
(paper: h2c' = W1·h2c + W2·c2c, one linear layer over [h2c, c2c] as the authors wrote it), run in
numpy by stages/networks/prior_layer.py. Imported by training only: recognition never loads torch.
"""

from __future__ import annotations

import sys
from typing import Any

import torch
from torch import nn

from mlnseq import networks


class SequenceClassifier(nn.Module):
    """Body -> h2c -> (PriorLayer) -> log-softmax, one class distribution per frame."""

    def __init__(self, config: Any):
        super().__init__()
        self.config = config
        self.kind = networks.module_of(config.cell)
        self.add_module(self.kind.BODY, self.kind.torch_body(config))
        self.h2c = nn.Linear(config.hidden_size, config.n_classes)
        self.prior = nn.Linear(2 * config.n_classes, config.n_classes) if config.prior_layer else None

    def forward(
        self, features: torch.Tensor, prior: torch.Tensor | None = None, state: Any = None
    ) -> tuple[torch.Tensor, Any]:
        """features [B, T, F], prior [B, T, C] -> class log-probabilities [B, T, C] and the last state.

        Every body is causal, so padding appended after a sequence never changes its outputs.
        """
        hidden, state = getattr(self, self.kind.BODY)(features, state)
        scores = self.h2c(hidden)  # h2c: hidden state -> class scores
        if self.prior is not None:
            if prior is None:
                raise ValueError("a PriorLayer model needs the MLN class input of every frame")
            scores = self.prior(torch.cat([scores, prior], dim=-1))
        return torch.log_softmax(scores, dim=-1), state

    def auxiliary_loss(self, log_probs: torch.Tensor, valid: torch.Tensor,
                       weight: torch.Tensor | None = None) -> torch.Tensor | None:
        """A type's training loss beside the NLL (the TCN's smoothing), or None; ``valid`` [..., B, T] marks real
        frames; the sequences' mean, or with ``weight`` [..., B] their weighted sum."""
        extra = getattr(self.kind, "auxiliary_loss", None)
        return None if extra is None else extra(self.config, log_probs, valid, weight)

    @property
    def side_by_side_at_most(self) -> int:
        """How many networks of this one's type and shape are fitted side by side at once (:meth:`side_by_side`);
        1: one at a time."""
        if not hasattr(self.kind, "torch_bodies_side_by_side"):
            return 1
        at_most = getattr(self.kind, "side_by_side_at_most", None)
        return sys.maxsize if at_most is None else at_most(self.config)

    def side_by_side_weights(self, stacked: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The weights G networks of this one's shape are fitted with side by side (leaves that require gradients),
        from theirs stacked ([G, ...] under the state dict's names): stacked, unless the type lays them out its
        own way (``side_by_side_weights``)."""
        layout = getattr(self.kind, "side_by_side_weights", None)
        weights = stacked if layout is None else layout(self.config, stacked)
        return {name: weight.requires_grad_() for name, weight in weights.items()}

    def side_by_side_stacked(self, weights: dict[str, torch.Tensor], g: int) -> dict[str, torch.Tensor]:
        """The weights fitted side by side (:meth:`side_by_side_weights`) as the G networks' own, stacked."""
        unstack = getattr(self.kind, "side_by_side_stacked", None)
        return weights if unstack is None else unstack(self.config, weights, g)

    def side_by_side(self, params: dict[str, torch.Tensor], features: torch.Tensor,
                     prior: torch.Tensor | None) -> torch.Tensor:
        """G networks of this one's shape at once, their weights in ``params`` (:meth:`side_by_side_weights`): each
        network's features [G, B, T, F] (and prior [G, B, T, C]) -> log-probabilities [G, B, T, C]."""
        hidden = self.kind.torch_bodies_side_by_side(self.config, params, features)
        g, b, t, _ = hidden.shape
        scores = affine(hidden.reshape(g, b * t, -1), params["h2c.weight"], params["h2c.bias"])
        if self.prior is not None:
            scores = affine(torch.cat([scores, prior.reshape(g, b * t, -1)], dim=-1), params["prior.weight"],
                            params["prior.bias"])
        return torch.log_softmax(scores, dim=-1).view(g, b, t, -1)


def merged(models: list[SequenceClassifier]) -> SequenceClassifier:
    """One network that computes the mean of ``models``' class scores (before the log-softmax): an ensemble of networks
    of one shape as one wider network of their type (its ``merged_body``), its h2c each body's h2c over G, and with a
    PriorLayer each network's PriorLayer folded into it (h2c' = mean of P_h·h2c; PriorLayer' = [I, mean of P_c]); a
    new network on the CPU (one: its copy)."""
    first, g = models[0], len(models)
    states = [{k: v.detach().cpu() for k, v in m.state_dict().items()} for m in models]
    dtype = next(first.parameters()).dtype
    if g == 1:
        model = SequenceClassifier(first.config).to(dtype)
        model.load_state_dict(states[0])
        return model
    body = first.kind.BODY
    config, weights = first.kind.merged_body(first.config, [{k: v for k, v in s.items() if k.startswith(body + ".")}
                                                           for s in states])
    h2c, bias = [s["h2c.weight"] / g for s in states], [s["h2c.bias"] / g for s in states]
    if first.prior is not None:
        c = first.config.n_classes
        h2c = [s["prior.weight"][:, :c] @ w for s, w in zip(states, h2c)]
        bias = [s["prior.weight"][:, :c] @ b for s, b in zip(states, bias)]
        from_mln = sum(s["prior.weight"][:, c:] for s in states) / g
        weights["prior.weight"] = torch.cat([torch.eye(c, dtype=dtype), from_mln], 1)
        weights["prior.bias"] = sum(s["prior.bias"] for s in states) / g
    weights["h2c.weight"], weights["h2c.bias"] = torch.cat(h2c, 1), sum(bias)
    model = SequenceClassifier(config).to(dtype)
    model.load_state_dict(weights)
    return model


def affine(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """G linear layers at once: inputs [G, N, in], weights [G, out, in], biases [G, out] -> [G, N, out]."""
    return torch.baddbmm(bias.unsqueeze(1), x, weight.transpose(1, 2))
