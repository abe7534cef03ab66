"""The rows a network fits and is scored on: every frame marked fit, val (held out for choosing), test or unused,
the training units of each, and the features standardised with the fit rows' mean and std (stages/train.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Any

import numpy as np

from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.parts import Part
from mlnseq.networks.fitting import Fitting, accuracy_and_loss, predict_log_probs
from mlnseq.choosing.workdir_inputs import FrameData
from mlnseq.timeline import sequences

if TYPE_CHECKING:
    import torch


class Select(StrEnum):
    """Which epoch is kept, and whether a validation part is held out for it."""

    NONE = "none"  # no validation part; the last epoch
    LAST = "last"  # a validation part; the last epoch
    VAL_ACCURACY = "val_accuracy"  # a validation part; the epoch of best frame accuracy on it


def assign_parts(data: FrameData, options: Any) -> tuple[np.ndarray, list[slice], list[slice]]:
    """Mark every row fit / val / test / unused; return the parts and the fit and val training units. ``options``: the
    train stage's (mode, window, select, val_fraction, train_fraction; and seed, where a fitting starts)."""
    parts = np.where(data.splits == Part.TRAIN, Part.TRAIN, Part.TEST).astype(object)
    units = sequences.training_units(options.mode, data.episodes, parts, data.labels, options.window)
    units = [u for u in units if parts[u.start] == Part.TRAIN]
    if not units:
        raise BadInput("frames.parquet has no training frames: rerun `mlnseq collect` with a training split")
    val_units: list[slice] = []
    if options.select != Select.NONE:
        if len(units) < 2:
            raise BadInput(f"--select {options.select} needs at least 2 training sequences; use --select none")
        n_val = max(1, round(options.val_fraction * len(units)))
        units, val_units = units[:-n_val], units[-n_val:]
    fit_units = units[: max(1, math.ceil(options.train_fraction * len(units)))]
    for unit in units[len(fit_units):]:
        parts[unit] = Part.UNUSED
    for unit in val_units:
        parts[unit] = Part.VAL
    for unit in fit_units:
        parts[unit] = Part.FIT
    return parts.astype(str), fit_units, val_units


LOGGED = ((Part.TRAIN, Part.FIT), (Part.VAL, Part.VAL), (Part.TEST, Part.TEST))  # the log's split -> rows' part


@dataclass(frozen=True)
class Rows:
    """The rows of a network's fitting: their parts, the fit and val units, and the inputs standardised with the
    fit rows' mean and std."""

    parts: np.ndarray
    fit_units: list[slice]
    val_units: list[slice]
    mean: np.ndarray
    std: np.ndarray
    features: np.ndarray
    prior: np.ndarray | None

    @classmethod
    def of(cls, data: FrameData, options: Any) -> Rows:
        parts, fit_units, val_units = assign_parts(data, options)
        fit_rows = parts == Part.FIT
        mean = data.features[fit_rows].mean(0)
        std = data.features[fit_rows].std(0)
        std = np.where(std > 1e-8, std, 1.0).astype(np.float32)
        features = ((data.features - mean) / std).astype(np.float32)
        prior = None if data.prior is None else data.prior.astype(np.float32)
        return cls(parts, fit_units, val_units, mean.astype(np.float32), std, features, prior)

    def start(self, data: FrameData, config: Any, options: Any, device: torch.device) -> Fitting:
        return Fitting.start(config, self.features, self.prior, data.labels, self.fit_units, options.seed, device)

    def warnings(self, data: FrameData) -> list[str]:
        """A class of the test split that no fit row has."""
        test = data.labels[data.splits == Part.TEST]
        missing = sorted(int(k) for k in set(test) - set(data.labels[self.parts == Part.FIT]))
        if not missing:
            return []
        return [f"classes {missing} occur in the test split but not in the training frames used; "
                "the model cannot predict them well"]

    def measure(self, fitting: Fitting, data: FrameData, mode: str) -> dict[Part, tuple[float, float]]:
        """Frame accuracy and NLL of each logged part that has rows (train: the fit rows), each sequence run from
        a fresh state."""
        every = sequences.sequences(mode, data.episodes, self.parts, data.labels)
        spans = [s for _, part in LOGGED for s in every if self.parts[s.start] == part]
        log_probs = predict_log_probs(fitting.model, spans, self.features, self.prior, fitting.device)
        return {name: accuracy_and_loss(log_probs, data.labels, self.parts == part)
                for name, part in LOGGED if (self.parts == part).any()}
