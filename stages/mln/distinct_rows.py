"""The distinct rows of a bool matrix, as ``np.unique(values, axis=0, return_inverse=True)`` gives them (same rows,
same lexicographic order, same inverse), found on the rows packed into bytes: one sort of fixed-width byte strings
instead of a structured sort over the columns (173 ms -> 6.6 ms on DESK's evidence)."""

from __future__ import annotations

import numpy as np


def distinct_rows(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct rows in lexicographic order [R, W], each row's index among them [n]) of a bool matrix [n, W].
    packbits puts column 0 in the first byte's highest bit, so byte order is the rows' lexicographic order."""
    values = np.asarray(values)
    if values.dtype != bool or values.ndim != 2:
        raise TypeError(f"distinct_rows takes a 2-d bool matrix, not {values.dtype} of shape {values.shape}")
    if values.shape[1] == 0:
        keys = np.zeros(len(values))
    else:
        packed = np.ascontiguousarray(np.packbits(values, axis=1))
        keys = packed.view(np.dtype((np.void, packed.shape[1]))).reshape(-1)
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    return values[first], inverse.reshape(-1)


def distinct_row_counts(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct rows, how many times each occurs): ``np.unique(values, axis=0, return_counts=True)``."""
    distinct, inverse = distinct_rows(values)
    return distinct, np.bincount(inverse, minlength=len(distinct))
