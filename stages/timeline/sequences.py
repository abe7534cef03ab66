"""Cutting frames into sequences and batching them for the recurrent networks.

Rows are frames in file order. A *block* is a maximal run of rows with the same episode and the
same part (train, val, test, ...). Two modes, chosen at training:

- ``segment``: the paper's protocol; every ground-truth segment (maximal run of one label within a
  block) is its own sequence, the hidden state reset at each.
- ``stream``: a block is one sequence, no knowledge of label boundaries. For training, blocks are cut
  into windows of a fixed length that carry no state; inference runs over whole blocks.
"""

from __future__ import annotations

import numpy as np

MODES = ("segment", "stream")


def run_starts(*keys: np.ndarray) -> np.ndarray:
    """The first row of each maximal run of consecutive rows on which every key array is constant (a run of one
    class, of one episode and class, ...): the one place runs are found."""
    n = len(keys[0])
    change = np.zeros(n, dtype=bool)
    change[:1] = True
    for key in keys:
        key = np.asarray(key)
        change[1:] |= key[1:] != key[:-1]
    return np.flatnonzero(change)


def runs(*keys: np.ndarray) -> list[slice]:
    """Maximal runs of consecutive rows on which every key array is constant."""
    starts = run_starts(*keys)
    stops = np.append(starts[1:], len(keys[0]))
    return [slice(int(a), int(b)) for a, b in zip(starts, stops)]


def blocks(episodes: np.ndarray, parts: np.ndarray) -> list[slice]:
    """Maximal runs of one episode and one part."""
    return runs(episodes, parts)


def segments(episodes: np.ndarray, parts: np.ndarray, labels: np.ndarray) -> list[slice]:
    """Ground-truth segments: maximal runs of one label within a block."""
    return runs(episodes, parts, labels)


def sequences(mode: str, episodes: np.ndarray, parts: np.ndarray, labels: np.ndarray) -> list[slice]:
    """The inference sequences of a mode: segments (segment) or whole blocks (stream)."""
    if mode == "segment":
        return segments(episodes, parts, labels)
    return blocks(episodes, parts)


def windows(spans: list[slice], length: int) -> list[slice]:
    """Cut each span into consecutive windows of at most ``length`` rows."""
    return [
        slice(start, min(start + length, span.stop))
        for span in spans
        for start in range(span.start, span.stop, length)
    ]


def training_units(
    mode: str, episodes: np.ndarray, parts: np.ndarray, labels: np.ndarray, window: int
) -> list[slice]:
    """The sequences a network trains on: segments, or windows of the blocks (stream)."""
    if mode == "segment":
        return segments(episodes, parts, labels)
    return windows(blocks(episodes, parts), window)


def pad(spans: list[slice], values: np.ndarray, fill: float = 0.0) -> np.ndarray:
    """Stack the rows of each span into a [len(spans), longest, ...] array, padded at the end."""
    longest = max(s.stop - s.start for s in spans)
    out = np.full((len(spans), longest, *values.shape[1:]), fill, dtype=values.dtype)
    for i, span in enumerate(spans):
        out[i, : span.stop - span.start] = values[span]
    return out


def lengths(spans: list[slice]) -> np.ndarray:
    return np.array([s.stop - s.start for s in spans], dtype=np.int64)
