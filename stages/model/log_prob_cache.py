"""A trained network's class log-probabilities over a workdir's frames, kept beside its checkpoint
(``models/METHOD.log-probs.npy``, :func:`mlnseq.catalog.artifacts.log_probs_cache_path`), so that the workdirs
that link one network (the reproduction's D-temporal, D-order ... link D's LSTM) run it once and read it back.

The cache is keyed by the digests of everything the values depend on: the checkpoint, the frames, the network's
other input (PriorLayer's prior) and the source of the numpy networks that run it; any change recomputes. It is
only a cache: one that cannot be read is recomputed, one that cannot be written is not written."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput


def _networks_source() -> str:
    """Digest of the numpy networks' source files (what computes the values)."""
    from mlnseq import networks

    folder = Path(networks.__file__).parent
    digest = hashlib.sha256()
    for path in sorted(folder.glob("*.py")):
        digest.update(path.name.encode() + path.read_bytes())
    return digest.hexdigest()[:16]


def cache_key(checkpoint: Path, frames: Path, prior: np.ndarray | None) -> str:
    """What the cached values were computed from."""
    prior_digest = "none" if prior is None else hashlib.sha256(
        f"{prior.shape} {prior.dtype}".encode() + np.ascontiguousarray(prior).tobytes()).hexdigest()[:16]
    digests = (artifacts.file_digest(checkpoint), artifacts.file_digest(frames), prior_digest, _networks_source())
    return "-".join(digests)


def cached_log_probs(checkpoint: Path, frames: Path, prior: np.ndarray | None,
                     compute: Callable[[], np.ndarray]) -> np.ndarray:
    """``compute()`` (the network over every frame), or the values a run with the same key stored."""
    path = artifacts.log_probs_cache_path(checkpoint)
    key = cache_key(checkpoint, frames, prior)
    try:
        with open(path, "rb") as handle:  # the key's line, then the array as np.save writes it
            if handle.readline().decode("ascii", "replace").strip() == key:
                return np.load(handle, allow_pickle=False)
    except (OSError, ValueError, EOFError):
        pass  # absent or unreadable: computed again
    values = compute()
    try:
        with artifacts.atomic_path(path) as staged, open(staged, "wb") as handle:
            handle.write(key.encode("ascii") + b"\n")
            np.save(handle, values, allow_pickle=False)  # no time stamp: the same values, the same bytes
    except BadInput:
        pass  # a folder we cannot write to: the values are still right, only not kept
    return values
