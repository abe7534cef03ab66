"""How a network's weights are updated: the authors' plain SGD at a fixed rate, an epoch at a time (the paper's
reproduction), or a budget of updates that settles (Adam, its rate warmed up, the weights' moving average kept,
stopped where the folds' held-out parts score best: stages/choosing/stopping.py).
The fitting itself is in stages/networks/fitting.py."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # torch loads only when a network is built or run
    import torch


class Optimizer(StrEnum):
    """How the weights move."""

    SGD = "sgd"  # the authors': plain SGD at a fixed rate, a whole number of epochs (the paper's reproduction)
    ADAM = "adam"  # Adam over a budget of updates, the weights' moving average kept
    AVERAGED = "averaged"  # plain SGD at the authors' rate over a budget of updates, the weights' moving average kept


SGD_RATE = 0.1  # the authors'


def member_seeds(seed: int, members: int) -> list[int]:
    """The seeds of the ``members`` networks averaged into the network of ``seed`` (one: ``seed`` itself)."""
    return [seed * members + i for i in range(members)]


@dataclass(frozen=True)
class Training:
    """How networks are trained: the optimizer, ``epochs`` passes over a network's fit units, ``batch_size`` units an
    update, the rate (None: the optimizer's own) and, with Adam, at most ``most`` updates (0: no cap), so that the
    cost stops growing with the data once that many have been made."""

    optimizer: Optimizer = Optimizer.SGD
    epochs: int = 100
    batch_size: int = 4
    learning_rate: float | None = None
    most: int = 0

    @property
    def rate(self) -> float:
        if self.learning_rate is not None:
            return self.learning_rate
        return Settling().learning_rate if self.optimizer == Optimizer.ADAM else SGD_RATE

    def per_epoch(self, units: int) -> int:
        """Updates a pass over ``units`` fit units takes."""
        return math.ceil(units / self.batch_size)

    def updates(self, units: int) -> int:
        """Adam's budget for networks trained on ``units`` fit units."""
        wanted = self.epochs * self.per_epoch(units)
        return wanted if not self.most else max(1, min(wanted, self.most))


@dataclass(frozen=True)
class Settling:
    """Adam's settings: the rate, warmed up over the first ``warmup`` share of the budget, then constant; the kept
    weights an exponential moving average of the weights passed through, over about ``averaged`` of the budget."""

    learning_rate: float = 3e-3
    warmup: float = 0.05
    averaged: float = 0.1
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-8

    def rate(self, step: int, steps: int) -> float:
        """The rate of update ``step`` (0-based) of ``steps``."""
        warm = max(1, round(self.warmup * steps))
        return self.learning_rate * min(1.0, (step + 1) / warm)

    def decay(self, steps: int) -> float:
        """The moving average's decay per update."""
        return 1.0 - 1.0 / max(1.0, self.averaged * steps)


class Adam:
    """Adam on a list of weight tensors, written out (torch.optim's first use imports torch._dynamo, a second or two
    of every run): each weight's moving means of its gradient and squared gradient, elementwise, so networks fitted
    side by side in one layer (their blocks apart, zero between) move exactly as each would alone."""

    def __init__(self, parameters: list[torch.Tensor], settling: Settling):
        import torch

        self.parameters, self.settling, self.count = parameters, settling, 0
        self.first = [torch.zeros_like(p) for p in parameters]
        self.second = [torch.zeros_like(p) for p in parameters]

    def step(self, rate: float) -> None:
        import torch

        beta1, beta2 = self.settling.betas
        self.count += 1
        correction1, correction2 = 1 - beta1 ** self.count, 1 - beta2 ** self.count
        with torch.no_grad():
            for p, m, v in zip(self.parameters, self.first, self.second):
                m.mul_(beta1).add_(p.grad, alpha=1 - beta1)
                v.mul_(beta2).addcmul_(p.grad, p.grad, value=1 - beta2)
                denominator = (v / correction2).sqrt_().add_(self.settling.eps)
                p.addcdiv_(m, denominator, value=-rate / correction1)


class Plain:
    """Plain SGD's update on a list of weight tensors (``step`` after their gradients)."""

    def __init__(self, parameters: list[torch.Tensor], settling: Settling):
        self.parameters = parameters

    def step(self, rate: float) -> None:
        import torch

        with torch.no_grad():
            for parameter in self.parameters:
                parameter.add_(parameter.grad, alpha=-rate)


class MovingAverage:
    """The exponential moving average of weight tensors, from their first values."""

    def __init__(self, parameters: list[torch.Tensor], decay: float):
        self.parameters, self.decay = parameters, decay
        self.mean = [p.detach().clone() for p in parameters]

    def add(self) -> None:
        import torch

        with torch.no_grad():
            for mean, p in zip(self.mean, self.parameters):
                mean.mul_(self.decay).add_(p.detach(), alpha=1 - self.decay)


class Batches:
    """A network's fit units drawn a batch at a time from one permutation after another (a batch may span two), from
    its own generator: the same stream however many networks are fitted beside it."""

    def __init__(self, units: int, rng: np.random.Generator):
        self.units, self.rng, self.order, self.at = units, rng, np.zeros(0, dtype=np.int64), 0

    def next(self, size: int) -> np.ndarray:
        size = min(size, self.units)
        while len(self.order) - self.at < size:
            self.order = np.concatenate([self.order[self.at:], self.rng.permutation(self.units)])
            self.at = 0
        batch = self.order[self.at : self.at + size]
        self.at += size
        return batch
