"""Fitting a network with torch: plain SGD over padded sequences, and its per-epoch evaluation. The train stage
decides which rows fit and which are scored (stages/train.py); recognition runs a trained network in numpy
(stages/networks/network.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from mlnseq import networks
from mlnseq.networks.updates import Adam, Batches, MovingAverage, Optimizer, Plain, Settling, Training
from mlnseq.timeline import sequences

if TYPE_CHECKING:  # torch loads only when a network is built or run
    import torch

    from mlnseq.networks.classifier import SequenceClassifier


def resolve_device(name: str) -> torch.device:
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def set_threads() -> None:
    """Small recurrent nets run fastest on one thread (measured: 8x faster than two on this 2-core CPU)."""
    import torch

    torch.set_num_threads(1)


def predict_log_probs(
    model: SequenceClassifier, spans: list[slice], features: np.ndarray, prior: np.ndarray | None,
    device: torch.device,
) -> np.ndarray:
    """Class log-probabilities of every row covered by ``spans`` (each span a fresh sequence): the per-epoch
    evaluation of training."""
    import torch

    model.eval()
    out = np.zeros((len(features), model.config.n_classes), dtype=np.float32)
    ordered = sorted(spans, key=lambda s: s.stop - s.start)  # similar lengths share a batch
    for i in range(0, len(ordered), networks.INFERENCE_BATCH):
        batch = ordered[i : i + networks.INFERENCE_BATCH]
        x = torch.from_numpy(sequences.pad(batch, features)).to(device)
        p = None if prior is None else torch.from_numpy(sequences.pad(batch, prior)).to(device)
        with torch.inference_mode():
            log_probs = model(x, p)[0].cpu().numpy()
        for j, span in enumerate(batch):
            out[span] = log_probs[j, : span.stop - span.start]
    return out


def accuracy_and_loss(log_probs: np.ndarray, labels: np.ndarray, rows: np.ndarray) -> tuple[float, float]:
    """Frame accuracy and mean NLL of ``rows``."""
    if not rows.any():
        return float("nan"), float("nan")
    lp = log_probs[rows]
    y = labels[rows]
    return float((lp.argmax(1) == y).mean()), float(-lp[np.arange(len(y)), y].mean())


def frame_losses(log_probs: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Each frame's NLL [..., T] of its label; 0 on padding (label -100)."""
    import torch

    return torch.nn.functional.nll_loss(log_probs.reshape(-1, log_probs.shape[-1]), labels.reshape(-1),
                                        reduction="none", ignore_index=-100).view(labels.shape)


def gradients(parameters: list[torch.Tensor], loss: torch.Tensor) -> None:
    """The gradients of ``loss``, anew, in each parameter's ``grad``."""
    for parameter in parameters:
        parameter.grad = None
    loss.backward()


def descend(parameters: list[torch.Tensor], loss: torch.Tensor, learning_rate: float) -> None:
    """One step of plain SGD on ``loss``: the gradients anew, then the update torch.optim.SGD makes without momentum
    (whose first use imports torch._dynamo, a second or two of every training run's start-up)."""
    import torch

    gradients(parameters, loss)
    with torch.no_grad():
        for parameter in parameters:
            parameter.add_(parameter.grad, alpha=-learning_rate)


@dataclass
class Fitting:
    """A network being fitted: the model, its fit units padded into tensors (features, prior, labels padded with
    -100, lengths) and the generator of the batch order."""

    model: SequenceClassifier
    tensors: tuple[Any, Any, Any, Any]
    rng: np.random.Generator
    device: torch.device

    @classmethod
    def start(cls, config: Any, features: np.ndarray, prior: np.ndarray | None, labels: np.ndarray,
              fit_units: list[slice], seed: int, device: torch.device) -> Fitting:
        """A new network of ``config`` (its initial weights from ``seed``) over the rows of ``fit_units``."""
        import torch

        from mlnseq.networks.classifier import SequenceClassifier

        torch.manual_seed(seed)
        model = SequenceClassifier(config).to(device)
        tensors = (torch.from_numpy(sequences.pad(fit_units, features)).to(device),
                   None if prior is None else torch.from_numpy(sequences.pad(fit_units, prior)).to(device),
                   torch.from_numpy(sequences.pad(fit_units, labels, fill=-100)).to(device),
                   torch.as_tensor(sequences.lengths(fit_units), device=device))
        return cls(model, tensors, np.random.default_rng(seed), device)

    @property
    def parameters(self) -> list[torch.Tensor]:
        return list(self.model.parameters())

    @property
    def members(self) -> list[Fitting]:
        return [self]

    def write_back(self, weights: list[torch.Tensor] | None = None) -> None:
        """The model holds its weights (``weights``: others in their place, in the order of :attr:`parameters`)."""
        import torch

        if weights is not None:
            with torch.no_grad():
                for parameter, weight in zip(self.parameters, weights):
                    parameter.copy_(weight)

    def epoch(self, batch_size: int, learning_rate: float) -> None:
        """One pass of SGD over the fit units in a random order, ``batch_size`` units a step."""
        parameters = self.parameters
        self.model.train()
        order = self.rng.permutation(len(self.tensors[3]))
        for start in range(0, len(order), batch_size):
            descend(parameters, self.loss([order[start : start + batch_size]], batch_size), learning_rate)

    def loss(self, batches: list[np.ndarray], width: int) -> torch.Tensor:
        """The training loss of one batch of fit units (``batches``: this network's one)."""
        import torch

        x_all, p_all, y_all, n_all = self.tensors
        index = torch.as_tensor(batches[0], device=self.device)
        longest = int(n_all[index].max())
        y = y_all[index, :longest]
        log_probs = self.model(x_all[index, :longest], None if p_all is None else p_all[index, :longest])[0]
        frame_loss = frame_losses(log_probs, y)
        # NLLLoss averaged within each sequence, then over sequences, as batch-size-1 SGD weighs them
        loss = (frame_loss.sum(1) / n_all[index]).mean()
        extra = self.model.auxiliary_loss(log_probs, y != -100)
        return loss if extra is None else loss + extra


class SideBySide:
    """Networks of one shape fitted as one batched network (``SequenceClassifier.side_by_side``), an epoch at a time.
    Each keeps its rows, batch order and plain SGD, so its updates are those :meth:`Fitting.epoch` makes (up to
    rounding); a network whose epoch has ended waits, its batch all padding and its gradient zero. Their models hold
    the fitted weights after :meth:`write_back`."""

    def __init__(self, fittings: list[Fitting]):
        import torch

        self.fittings, self.model, self.device = fittings, fittings[0].model, fittings[0].device
        self.names = [name for name, _ in self.model.named_parameters()]
        self.params = self.model.side_by_side_weights(
            {name: torch.stack([f.model.get_parameter(name).detach() for f in fittings]) for name in self.names})
        self.tensors = _stacked(fittings)
        self.groups = torch.arange(len(fittings), device=self.device).unsqueeze(1)

    @property
    def parameters(self) -> list[torch.Tensor]:
        return list(self.params.values())

    @property
    def members(self) -> list[Fitting]:
        return self.fittings

    def epoch(self, batch_size: int, learning_rate: float) -> None:
        parameters = self.parameters
        self.model.train()
        orders = [f.rng.permutation(len(f.tensors[3])) for f in self.fittings]
        for start in range(0, max(map(len, orders)), batch_size):
            descend(parameters, self.loss([order[start : start + batch_size] for order in orders], batch_size),
                    learning_rate)

    def loss(self, batches: list[np.ndarray], width: int) -> torch.Tensor:
        """The networks' summed training loss of one batch of fit units each (``batches``: each network's units, a
        network whose epoch has ended none: it waits, its batch all padding and its gradient zero)."""
        import torch

        x_all, p_all, y_all, n_all = self.tensors
        blank = x_all.shape[1] - 1  # the padding unit, after every network's own
        groups = self.groups
        index = torch.as_tensor(_side_by_side_batch(batches, blank, width), device=self.device)
        real, lengths = index != blank, n_all[groups, index]
        count = real.sum(1, keepdim=True).clamp(min=1)
        longest = int(lengths.max())
        y = y_all[groups, index, :longest]
        log_probs = self.model.side_by_side(self.params, x_all[groups, index, :longest],
                                            None if p_all is None else p_all[groups, index, :longest])
        frame_loss = frame_losses(log_probs, y)
        # each network's mean over its batch; padding has no labels, so no loss
        loss = ((frame_loss.sum(-1) / lengths).sum(1, keepdim=True) / count).sum()
        extra = self.model.auxiliary_loss(log_probs, y != -100, real.to(log_probs.dtype) / count)
        return loss if extra is None else loss + extra

    def write_back(self, weights: list[torch.Tensor] | None = None) -> None:
        """Each network's model holds its weights (``weights``: others in the place of the fitted ones, in the order of
        :attr:`parameters`)."""
        import torch

        params = self.params if weights is None else dict(zip(self.params, weights))
        with torch.no_grad():
            stacked = self.model.side_by_side_stacked(params, len(self.fittings))
            for g, fitting in enumerate(self.fittings):
                for name in self.names:
                    fitting.model.get_parameter(name).copy_(stacked[name][g])


class Together:
    """Networks of one shape fitted an epoch at a time: side by side (:class:`SideBySide`) in groups of as many as
    their type fits at once, else one after another. Each ends where it would alone (up to rounding)."""

    def __init__(self, fittings: list[Fitting]):
        most = fittings[0].model.side_by_side_at_most
        groups = [fittings[i : i + most] for i in range(0, len(fittings), most)]
        self.groups = [SideBySide(group) if len(group) > 1 else group[0] for group in groups]

    def epoch(self, batch_size: int, learning_rate: float) -> None:
        for group in self.groups:
            group.epoch(batch_size, learning_rate)

    def write_back(self) -> None:
        """Each network's model holds its weights so far."""
        for group in self.groups:
            group.write_back()


class Settle:
    """Networks fitted together (:class:`Together`'s groups) over a budget of ``updates`` updates by Adam, the rate
    warmed up then constant, the weights' moving average kept (``updates.Settling``). Each network draws its own
    batches from its own generator, so each makes the updates it would alone (up to rounding)."""

    def __init__(self, together: Together, updates: int, batch_size: int, settling: Settling, optimizer: Optimizer):
        self.together, self.updates, self.batch_size, self.settling, self.done = together, updates, batch_size, \
            settling, 0
        self.aside: list[tuple[Fitting, list[torch.Tensor]]] = []
        stepper, decay = Adam if optimizer == Optimizer.ADAM else Plain, settling.decay(updates)
        self.runs = [(group, stepper(group.parameters, settling), MovingAverage(group.parameters, decay),
                      [Batches(len(f.tensors[3]), f.rng) for f in group.members]) for group in together.groups]

    def advance(self, count: int) -> None:
        """The next ``count`` updates (fewer where the budget ends)."""
        end = min(self.updates, self.done + count)
        self._resume()
        for group, adam, average, batches in self.runs:
            group.model.train()
            for step in range(self.done, end):
                gradients(adam.parameters, group.loss([b.next(self.batch_size) for b in batches], self.batch_size))
                adam.step(self.settling.rate(step, self.updates))
                average.add()
        self.done = end

    def write_back(self) -> None:
        """Each network's model holds the moving average of its weights so far (a network fitted alone is its model:
        its weights are set aside, and back before the next update)."""
        self._resume()
        for group, _, average, _ in self.runs:
            if isinstance(group, Fitting):
                self.aside.append((group, [p.detach().clone() for p in group.parameters]))
            group.write_back(average.mean)

    def _resume(self) -> None:
        for group, weights in self.aside:
            group.write_back(weights)
        self.aside = []


FEWEST_EPOCHS = 20  # Adam with its updates capped: an epoch is a pass over the fit units or a 20th of them, the fewer


class Schedule:
    """Networks of one shape fitted together (:class:`Together`) as ``training`` says, an epoch at a time: plain SGD, a
    pass over each network's fit units an epoch; or Adam over its budget of updates for ``units`` fit units (every
    network makes as many: the fold networks those of the whole training split), an epoch as many updates as a pass
    over ``units`` takes (where the cap cuts the budget short, at most a twentieth of it), the weights' moving average
    kept."""

    def __init__(self, fittings: list[Fitting], training: Training, units: int):
        self.training, self.together = training, Together(fittings)
        self.settle = None
        self.epochs = training.epochs
        if training.optimizer != Optimizer.SGD:
            updates, self.per_epoch = training.updates(units), training.per_epoch(units)
            if updates < training.epochs * self.per_epoch:  # capped: at least FEWEST_EPOCHS epochs all the same
                self.per_epoch = min(self.per_epoch, math.ceil(updates / FEWEST_EPOCHS))
            self.epochs = math.ceil(updates / self.per_epoch)
            self.settle = Settle(self.together, updates, training.batch_size,
                                 replace(Settling(), learning_rate=training.rate), training.optimizer)

    def epoch(self) -> None:
        """The next epoch."""
        if self.settle is None:
            self.together.epoch(self.training.batch_size, self.training.rate)
        else:
            self.settle.advance(self.per_epoch)

    def write_back(self) -> None:
        """Each network's model holds its weights so far (with Adam, their moving average)."""
        if self.settle is None:
            self.together.write_back()
        else:
            self.settle.write_back()

    def run(self) -> None:
        """Every epoch; then each network's model holds the weights kept."""
        for _ in range(self.epochs):
            self.epoch()
        self.write_back()


def fit_together(fittings: list[Fitting], epochs: int, batch_size: int, learning_rate: float) -> None:
    """Fit the networks for ``epochs`` of plain SGD (:class:`Together`)."""
    Schedule(fittings, Training(Optimizer.SGD, epochs, batch_size, learning_rate), 0).run()


def _stacked(fittings: list[Fitting]) -> tuple[Any, Any, Any, Any]:
    """Every network's fit units (features, prior, labels, lengths) stacked [G, U + 1, ...], padded at the end;
    unit U is padding in all."""
    import torch

    units = max(len(f.tensors[3]) for f in fittings) + 1
    longest = max(f.tensors[0].shape[1] for f in fittings)

    def stack(i: int, fill: float) -> Any:
        first = fittings[0].tensors[i]
        if first is None:
            return None
        out = torch.full((len(fittings), units, longest, *first.shape[2:]), fill, dtype=first.dtype,
                         device=first.device)
        for g, fitting in enumerate(fittings):
            tensor = fitting.tensors[i]
            out[g, : tensor.shape[0], : tensor.shape[1]] = tensor
        return out

    lengths = torch.ones((len(fittings), units), dtype=fittings[0].tensors[3].dtype, device=fittings[0].device)
    for g, fitting in enumerate(fittings):
        lengths[g, : len(fitting.tensors[3])] = fitting.tensors[3]
    return stack(0, 0.0), stack(1, 0.0), stack(2, -100), lengths


def _side_by_side_batch(batches: list[np.ndarray], blank: int, width: int) -> np.ndarray:
    """Each network's units of one step [G, width], filled up with the padding unit."""
    index = np.full((len(batches), width), blank, dtype=np.int64)
    for g, units in enumerate(batches):
        index[g, : len(units)] = units
    return index
