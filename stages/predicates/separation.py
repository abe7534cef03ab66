"""Which predicate values separate which classes: per class, the share of its training frames where each holds.

`mlnseq binarize --table` prints it to help write formulas: a value true in most frames of one class and few of
the others is a good body for ``Has("value", p) => Topic("class", p)``. Read on the training split only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl


@dataclass(frozen=True)
class ClassShares:
    """``shares[i, k]``: the share of class k's training frames where column i holds; ``overall[i]`` of all frames."""

    columns: list[str]
    classes: list[str]  # the classes the training split shows, in label order
    shares: np.ndarray  # [columns, classes]
    overall: np.ndarray  # [columns]: share of every frame (both splits)
    frames: int  # training frames read

    @property
    def spread(self) -> np.ndarray:
        """Per column: its largest class share minus its smallest (1: true in all of one class, none of another)."""
        return self.shares.max(axis=1) - self.shares.min(axis=1) if self.shares.size else np.zeros(len(self.columns))

    def best(self, n: int) -> list[int]:
        """The ``n`` columns of largest spread, largest first (ties in column order)."""
        return list(np.argsort(-self.spread, kind="stable")[:n])

    def marker(self, k: int) -> tuple[str, float, float]:
        """The column that most marks class k: (column, share in k, share in the other classes' frames at most)."""
        others = np.delete(self.shares, k, axis=1)
        margin = self.shares[:, k] - (others.max(axis=1) if others.size else 0.0)
        i = int(np.argmax(margin))
        return self.columns[i], float(self.shares[i, k]), float(others[i].max()) if others.size else 0.0


def class_shares(predicates: pl.DataFrame, columns: list[str], class_names: list[str]) -> ClassShares:
    """The per-class shares of ``columns`` on the training split of ``predicates`` (all frames if none train)."""
    overall = predicates.select(pl.col(c).mean() for c in columns).to_numpy()[0] if predicates.height else \
        np.zeros(len(columns))
    train = predicates.filter(pl.col("split") == "train")
    train = train if train.height else predicates
    labels = train["label"].to_numpy()
    present = sorted(set(labels.tolist()))
    values = train.select(columns).to_numpy().astype(np.float64)
    shares = np.stack([values[labels == k].mean(axis=0) for k in present], axis=1) if present else \
        np.zeros((len(columns), 0))
    names = [class_names[k] if 0 <= k < len(class_names) else f"C{k}" for k in present]
    return ClassShares(columns, names, shares, np.asarray(overall, dtype=np.float64), train.height)
