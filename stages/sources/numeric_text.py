"""Whitespace-separated numeric text, one frame a line (the DESK files, JIGSAWS kinematics)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mlnseq.catalog.errors import BadInput


def read_numeric_text(path: Path, n_columns: int | None, empty: str) -> np.ndarray:
    """The file's rows as float64, every line of ``n_columns`` values (None: as many as the first line);
    a bad value is named by file and line, an empty file says ``empty`` (what it should hold)."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise BadInput(f"cannot read {path}: {error}") from error
    rows: list[list[float]] = []
    width = n_columns
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        width = width or len(fields)
        if len(fields) != width:
            first = "" if n_columns else " as on the first line"
            raise BadInput(f"{path}:{number}: expected {width} columns{first}, found {len(fields)}")
        try:
            values = [float(field) for field in fields]
        except ValueError:
            raise BadInput(f"{path}:{number}: non-numeric value in {line.strip()[:60]!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise BadInput(f"{path}:{number}: NaN or infinite value; remove or repair that frame")
        rows.append(values)
    if not rows:
        raise BadInput(f"{path} is empty: expected {empty}")
    return np.asarray(rows, dtype=np.float64)
