"""Fitting a network with torch: plain SGD over padded sequences, and its per-epoch evaluation. The train stage
decides which rows fit and which are scored (stages/train.py); recognition runs a trained network in numpy
(stages/networks/network.py)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from mlnseq import networks
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


def descend(parameters: list[torch.Tensor], loss: torch.Tensor, learning_rate: float) -> None:
    """One step of plain SGD on ``loss``: the gradients anew, then the update torch.optim.SGD makes without momentum
    (whose first use imports torch._dynamo, a second or two of every training run's start-up)."""
    import torch

    for parameter in parameters:
        parameter.grad = None
    loss.backward()
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

    def epoch(self, batch_size: int, learning_rate: float) -> None:
        """One pass of SGD over the fit units in a random order, ``batch_size`` units a step."""
        import torch

        x_all, p_all, y_all, n_all = self.tensors
        parameters = list(self.model.parameters())
        self.model.train()
        order = self.rng.permutation(len(n_all))
        for start in range(0, len(order), batch_size):
            index = torch.as_tensor(order[start : start + batch_size], device=self.device)
            longest = int(n_all[index].max())
            y = y_all[index, :longest]
            log_probs = self.model(x_all[index, :longest], None if p_all is None else p_all[index, :longest])[0]
            frame_loss = frame_losses(log_probs, y)
            # NLLLoss averaged within each sequence, then over sequences, as batch-size-1 SGD weighs them
            loss = (frame_loss.sum(1) / n_all[index]).mean()
            extra = self.model.auxiliary_loss(log_probs, y != -100)
            descend(parameters, loss if extra is None else loss + extra, learning_rate)


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

    def epoch(self, batch_size: int, learning_rate: float) -> None:
        import torch

        x_all, p_all, y_all, n_all = self.tensors
        blank = x_all.shape[1] - 1  # the padding unit, after every network's own
        groups, parameters = self.groups, list(self.params.values())
        self.model.train()
        orders = [f.rng.permutation(len(f.tensors[3])) for f in self.fittings]
        for start in range(0, max(map(len, orders)), batch_size):
            index = torch.as_tensor(_side_by_side_batch(orders, start, batch_size, blank), device=self.device)
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
            descend(parameters, loss if extra is None else loss + extra, learning_rate)

    def write_back(self) -> None:
        import torch

        with torch.no_grad():
            stacked = self.model.side_by_side_stacked(self.params, len(self.fittings))
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
            if isinstance(group, SideBySide):
                group.write_back()


def fit_together(fittings: list[Fitting], epochs: int, batch_size: int, learning_rate: float) -> None:
    """Fit the networks for ``epochs`` (:class:`Together`)."""
    together = Together(fittings)
    for _ in range(epochs):
        together.epoch(batch_size, learning_rate)
    together.write_back()


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


def _side_by_side_batch(orders: list[np.ndarray], start: int, batch_size: int, blank: int) -> np.ndarray:
    """Each network's units of the step at ``start`` of its order [G, batch_size], filled up with the padding unit."""
    index = np.full((len(orders), batch_size), blank, dtype=np.int64)
    for g, order in enumerate(orders):
        units = order[start : start + batch_size]
        index[g, : len(units)] = units
    return index
