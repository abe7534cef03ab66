"""The fold networks: one per fold (and seed) fitted without its fold, all side by side, and their out-of-fold
predictions. With Adam (networks/updates.py), early stopping by cross-validation: the out-of-fold predictions scored
every few epochs, and the epoch where their NLL is lowest kept, for them and for the network of the whole training
split (stages/train.py). Only the training split is read: each fold's held-out part is training data its networks
did not fit."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from mlnseq.catalog.parts import Part
from mlnseq.choosing.folds import Folds
from mlnseq.choosing.training_rows import Rows, Select
from mlnseq.choosing.workdir_inputs import FrameData
from mlnseq.networks.fitting import Fitting, Schedule, predict_log_probs
from mlnseq.networks.updates import Optimizer, member_seeds
from mlnseq.timeline import sequences

if TYPE_CHECKING:
    import torch

    from mlnseq.networks.classifier import SequenceClassifier

CHECKS = 20  # the out-of-fold predictions are scored this many times over the budget
PATIENCE = 5  # checks in a row without a lower out-of-fold NLL, for any seed, end the fitting
ALONE_FRAMES = 20_000  # training frames from which each fold network is one network, not the mean of members


@dataclass(frozen=True)
class HeldOut:
    """A fold's held-out part: its sequences, its frames, and every frame's inputs as its networks read them."""

    spans: list[slice]
    frames: np.ndarray  # bool [n]
    features: np.ndarray
    prior: np.ndarray | None


def held_out_parts(rows: list[Rows], fold_data: list[FrameData], folds: Folds, mode: str) -> list[HeldOut]:
    """Each fold's held-out part (``rows``: each fold's networks' rows, standardised as they fit)."""
    parts = []
    for k, (fold_rows, data) in enumerate(zip(rows, fold_data)):
        spans = [s for s in sequences.sequences(mode, data.episodes, data.splits, data.labels)
                 if data.splits[s.start] == Part.HELDOUT]
        parts.append(HeldOut(spans, folds.fold == k, fold_rows.features, fold_rows.prior))
    return parts


def out_of_fold(models: list[SequenceClassifier], parts: list[HeldOut], device: torch.device) -> np.ndarray:
    """Every frame's class log-probabilities [n, C] by the network of ``models`` (one per fold) that did not fit it
    (0 where no fold holds it out)."""
    n, classes = len(parts[0].frames), models[0].config.n_classes
    out = np.zeros((n, classes), dtype=np.float32)
    for model, part in zip(models, parts):
        log_probs = predict_log_probs(model.to(device), part.spans, part.features, part.prior, device)
        out[part.frames] = log_probs[part.frames]
    return out


def nll(log_probs: np.ndarray, labels: np.ndarray, parts: list[HeldOut]) -> float:
    """The mean NLL of the held-out frames' labels."""
    held = np.logical_or.reduce([part.frames for part in parts])
    return float(-log_probs[held, labels[held]].mean())


def kept(networks: list[list[Fitting]]) -> list[SequenceClassifier]:
    """Each fold's network: its members' (``networks``: per fold) merged into one (classifier.merged)."""
    from mlnseq.networks.classifier import merged

    return [merged([member.model for member in members]) for members in networks]


def fit_stopped(schedule: Schedule, networks: list[list[list[Fitting]]], parts: list[HeldOut], labels: np.ndarray,
                device: torch.device) -> list[int]:
    """Fit the networks of ``schedule`` (``networks``: each seed's fold networks, each of its members, among them)
    epoch by epoch, score each seed's out-of-fold predictions every ``epochs / CHECKS`` epochs, and stop after
    ``PATIENCE`` checks without a lower NLL for any seed, or at the budget's end. Each seed's networks then hold their
    weights of its lowest check; returns that epoch per seed."""
    every = max(1, math.ceil(schedule.epochs / CHECKS))
    best: list[tuple[float, int, list[dict]]] = [(math.inf, schedule.epochs, [])] * len(networks)
    since = 0
    for epoch in range(1, schedule.epochs + 1):
        schedule.epoch()
        if epoch % every and epoch != schedule.epochs:
            continue
        schedule.write_back()
        improved = False
        for s, per_seed in enumerate(networks):
            score = nll(out_of_fold(kept(per_seed), parts, device), labels, parts)
            if score < best[s][0]:
                states = [{k: v.detach().clone() for k, v in m.model.state_dict().items()}
                          for members in per_seed for m in members]
                best[s], improved = (score, epoch, states), True
        since = 0 if improved else since + 1
        if since >= PATIENCE:
            break
    for per_seed, (_, _, states) in zip(networks, best):
        for member, state in zip([m for members in per_seed for m in members], states):
            member.model.load_state_dict(state)
    return [epoch for _, epoch, _ in best]


def fit_folds(fold_data: list[FrameData], config: Any, options: Any, device: torch.device, seeds: tuple[int, ...],
              units: int, folds: Folds) -> tuple[list[list[SequenceClassifier]], list[HeldOut], list[int] | None]:
    """Each seed's fold networks (each of :func:`fold_members` networks averaged), all side by side, each trained as
    the train stage trains without a validation part, nothing measured (their logs would not be kept): with SGD, the
    last epoch kept; with Adam (a budget of ``units`` fit units: the whole training split's), the epoch of the lowest
    out-of-fold NLL, also returned per seed. Returns them per seed and fold, and each fold's held-out part.
    ``options``: the train stage's."""
    options = replace(options, select=Select.NONE, members=fold_members(options.members, folds))
    rows = [Rows.of(data, options) for data in fold_data]
    networks = [[[part.start(data, config, replace(options, seed=member), device)
                  for member in member_seeds(seed, options.members)] for part, data in zip(rows, fold_data)]
                for seed in seeds]
    schedule = Schedule([m for per_seed in networks for members in per_seed for m in members], options.training,
                        units)
    parts = held_out_parts(rows, fold_data, folds, options.mode)
    stop = None
    if options.optimizer == Optimizer.SGD:
        schedule.run()
    else:
        stop = fit_stopped(schedule, networks, parts, fold_data[0].labels, device)
    return [kept(per_seed) for per_seed in networks], parts, stop


def fold_members(wanted: int, folds: Folds) -> int:
    """The networks averaged into each fold network: the train stage's ``wanted`` on little data, where the mean
    steadies networks fitted on a few recordings; one from ALONE_FRAMES training frames on, where a network fitted on
    four fifths of them is steady alone and its out-of-fold predictions only score and stop (the network kept is
    still the mean of ``wanted``)."""
    return 1 if int((folds.fold >= 0).sum()) >= ALONE_FRAMES else wanted
