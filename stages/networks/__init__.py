"""The network types and the one registry every caller reads (train, the recogniser, `info`, the CLI).

Each type is one module holding its config dataclass, the torch body that trains it and the numpy body
that runs it (whole sequences, and one frame at a time with its streaming state) side by side. Every
type shares the head (h2c, the MLN PriorLayer, log-softmax: stages/networks/prior_layer.py). Adding a
type: write its module with the interface of stages/networks/recurrent.py and add a row to ``TYPES``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, fields
from types import ModuleType
from typing import Any

from mlnseq.catalog.errors import BadInput

INFERENCE_BATCH = 256  # sequences side by side when a network predicts log-probabilities (torch and numpy)


@dataclass(frozen=True)
class NetworkType:
    """One row of the registry: the ``--cell`` name, the module that holds the type, what it is."""

    name: str
    module: str
    summary: str


TYPES = {t.name: t for t in (
    NetworkType("lstm", "mlnseq.networks.recurrent", "one-layer LSTM"),
    NetworkType("gru", "mlnseq.networks.recurrent", "one-layer GRU"),
    NetworkType("tcn", "mlnseq.networks.tcn", "causal temporal convolutional network (dilated 1-D convolutions)"),
)}
CELLS = tuple(TYPES)


def module_of(cell: str) -> ModuleType:
    """The module of a network type; an unknown one is a BadInput."""
    if cell not in TYPES:
        raise BadInput(f"unknown network type {cell!r}: choose one of {', '.join(CELLS)}")
    return importlib.import_module(TYPES[cell].module)


def config_of(model: dict[str, Any]) -> Any:
    """A network's config dataclass from the dict its checkpoint or model file holds."""
    config_type = module_of(model["cell"]).Config
    return config_type(**{f.name: model[f.name] for f in fields(config_type) if f.name in model})


def make_config(cell: str, **values: Any) -> Any:
    """The config of a new network of type ``cell``; a value that type has no field for must be its default
    (a non-default one is a BadInput naming the option)."""
    config_type = module_of(cell).Config
    names = {f.name for f in fields(config_type)}
    for name, value in values.items():
        if name not in names and value:
            raise BadInput(f"--{name.replace('_', '-')} {value}: the {cell} network has no such option "
                           f"(the types that have it: {', '.join(c for c in CELLS if _has(c, name))})")
    return config_type(cell=cell, **{k: v for k, v in values.items() if k in names})


def _has(cell: str, name: str) -> bool:
    return name in {f.name for f in fields(module_of(cell).Config)}


def describe(model: dict[str, Any]) -> str:
    """One line on a network's shape, as `mlnseq info` shows it."""
    return module_of(model["cell"]).describe(config_of(model))


def state_shapes(model: dict[str, Any]) -> dict[str, tuple[int, ...]]:
    """The arrays of a network's state dict and their shapes, from its configuration: the type's body and the
    shared head (h2c, and PriorLayer's linear layer if it has one)."""
    config = config_of(model)
    shapes = dict(module_of(model["cell"]).body_shapes(config))
    shapes |= {"h2c.weight": (config.n_classes, config.hidden_size), "h2c.bias": (config.n_classes,)}
    if config.prior_layer:
        shapes |= {"prior.weight": (config.n_classes, 2 * config.n_classes), "prior.bias": (config.n_classes,)}
    return shapes


def config_fields(cell: str) -> tuple[str, ...]:
    """The names of a network type's configuration (the keys its checkpoint and model file hold)."""
    return tuple(f.name for f in fields(module_of(cell).Config))


def config_types(cell: str) -> dict[str, str]:
    """A network type's configuration keys and the type each holds (int, float, bool or str)."""
    return {f.name: f.type if isinstance(f.type, str) else f.type.__name__ for f in fields(module_of(cell).Config)}
