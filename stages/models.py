"""The networks: a one-layer LSTM (or GRU) classifier, optionally with the MLN PriorLayer.

Paper (Rahman et al., RO-MAN 2021): the recurrent layer reads the standardised features of each
frame, a linear layer maps its hidden state to class scores (h2c), and a log-softmax gives the
class log-probabilities trained with NLLLoss. PriorLayer: h2c' = W1·h2c + W2·c2c, where
c2c is the frame's MLN class input; as in the authors' code it is one linear layer over the
concatenation [h2c, c2c].
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

CELLS = ("lstm", "gru")


@dataclass(frozen=True)
class ModelConfig:
    """The shape of a network; stored in every checkpoint."""

    n_features: int
    n_classes: int
    hidden_size: int = 32
    cell: str = "lstm"
    prior_layer: bool = False

    def to_dict(self) -> dict:
        return asdict(self)


State = torch.Tensor | tuple[torch.Tensor, torch.Tensor]


class SequenceClassifier(nn.Module):
    """Recurrent layer -> h2c -> (PriorLayer) -> log-softmax, one class distribution per frame."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.config = config
        recurrent = nn.LSTM if config.cell == "lstm" else nn.GRU
        self.rnn = recurrent(config.n_features, config.hidden_size, num_layers=1, batch_first=True)
        self.h2c = nn.Linear(config.hidden_size, config.n_classes)
        # PriorLayer: h2c' = W1·h2c + W2·c2c, one linear map of [h2c, c2c] as the authors wrote it
        self.prior = nn.Linear(2 * config.n_classes, config.n_classes) if config.prior_layer else None

    def forward(
        self, features: torch.Tensor, prior: torch.Tensor | None = None, state: State | None = None
    ) -> tuple[torch.Tensor, State]:
        """features [B, T, F], prior [B, T, C] -> class log-probabilities [B, T, C] and the last state.

        The network is causal, so padding appended after a sequence never changes its outputs.
        """
        hidden, state = self.rnn(features, state)
        scores = self.h2c(hidden)  # h2c: hidden state -> class scores
        if self.prior is not None:
            if prior is None:
                raise ValueError("a PriorLayer model needs the MLN class input of every frame")
            scores = self.prior(torch.cat([scores, prior], dim=-1))
        return torch.log_softmax(scores, dim=-1), state
