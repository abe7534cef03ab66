"""A workdir's trained networks on disk: ``models/<network>.pt``, a torch file holding the state dict and the
configuration it was trained with (features, classes, standardisation, options, input digests).

torch is imported only here and in training: a model file (``.mlnseq``) is recognised without it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput, StaleArtifact
from mlnseq.networks.network import Network

if TYPE_CHECKING:
    from mlnseq.networks.classifier import SequenceClassifier

CHECKPOINT_FORMAT = 1


@dataclass(frozen=True)
class Checkpoint:
    """A trained network (in numpy) with the configuration its checkpoint embeds."""

    network: Network
    config: dict[str, Any]

    @property
    def mode(self) -> str:
        return self.config["mode"]


def save_checkpoint(path: Path, model: SequenceClassifier, config: dict[str, Any]) -> Path:
    """Write a checkpoint atomically: an interrupted save leaves the previous file as it was."""
    import torch

    with artifacts.atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:  # a file object: the archive is named 'archive', not the random temp name
            torch.save({"config": {**config, "format": CHECKPOINT_FORMAT}, "state_dict": model.state_dict()}, handle)
    return path


def _read(path: Path, method: str) -> dict[str, Any]:
    """A checkpoint's saved dict (its configuration and state dict), its format checked."""
    import torch

    if not path.exists():
        raise BadInput(f"{path} not found: run `mlnseq train --method {method}` first")
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
        config = saved["config"]
    except Exception as error:  # torch raises many types for a foreign or truncated file
        raise BadInput(f"{path} is not an mlnseq checkpoint ({error}); "
                       f"rerun `mlnseq train --method {method}`") from error
    if config.get("format") != CHECKPOINT_FORMAT:
        raise BadInput(f"{path} has checkpoint format {config.get('format')}, this mlnseq reads "
                       f"{CHECKPOINT_FORMAT}; rerun `mlnseq train --method {method}`")
    return saved


def checkpoint_config(workdir: Path, method: str) -> dict[str, Any]:
    """The configuration ``models/<method>.pt`` embeds (not checked against the workdir's inputs)."""
    return _read(artifacts.checkpoint_path(workdir, method), method)["config"]


def load_checkpoint(workdir: Path, method: str, frames_meta: dict[str, Any] | None = None) -> Checkpoint:
    """Load ``models/<method>.pt``; refuse one made from other inputs, features or classes."""
    path = artifacts.checkpoint_path(workdir, method)
    saved = _read(path, method)
    config = saved["config"]
    if frames_meta is not None:
        for key in ("features", "classes"):
            if list(config[key]) != list(frames_meta[key]):
                raise BadInput(f"{path} was trained on {key} {config[key]}, but {artifacts.FRAMES} has "
                               f"{frames_meta[key]}; rerun `mlnseq train --method {method}`")
    for name, digest in config["inputs"].items():
        source = workdir / name
        if source.exists() and artifacts.file_digest(source) != digest:
            from mlnseq.catalog.rerun import command

            raise StaleArtifact(f"{path} was trained on an older {name}; rerun "
                                f"`{command('train', config.get('options'))}`")
    return Checkpoint(Network.from_state(config["model"], saved["state_dict"], config["mean"], config["std"]), config)
