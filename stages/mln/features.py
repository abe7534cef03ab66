"""Formula counts per class configuration, shared by the per-frame scores, the chain factors and CLL learning.

Classes are one-hot (exactly one per frame). For a per-frame formula f and a frame with evidence row r,
``unary[r, k]`` = (true groundings of f with class k) - (true groundings with every Topic atom false);
for a temporal formula and a consecutive pair q of evidence rows, ``pairwise[q, j, k]`` = (true groundings
with class j on the earlier frame and k on the later one) - (with no class on either). The differences
are all that matters: the baseline is the same for every configuration. A hard formula instead forbids
the configurations where one of its groundings is false.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from mlnseq.mln.grounding import EVIDENCE, AtomSpace, PairSpace, ground, next_atom, space_of, truth
from mlnseq.mln.syntax import Formula, Var, atoms


@dataclass(frozen=True)
class Counts:
    """Count differences of each formula on each configuration, and the configurations hard formulas forbid."""

    matrix: sparse.csr_matrix  # [configurations, formulas] float64
    forbidden: np.ndarray  # bool [configurations]


def _configurations(evidence: np.ndarray, n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows [evidence | one-hot class] for every (row, class), row-major; and the rows with no class."""
    n_rows = len(evidence)
    with_class = np.concatenate([np.repeat(evidence, n_classes, axis=0),
                                 np.tile(np.eye(n_classes, dtype=bool), (n_rows, 1))], axis=1)
    return with_class, np.concatenate([evidence, np.zeros((n_rows, n_classes), dtype=bool)], axis=1)


def _counts(formulas: Sequence[Formula], hard: Sequence[bool], space: AtomSpace | PairSpace,
            rows: np.ndarray, baseline: np.ndarray, repeat: int) -> Counts:
    """Counts of ``formulas`` (all on ``space``) on ``rows``; ``baseline`` holds one row per ``repeat`` rows."""
    entries, columns, values = [], [], []
    forbidden = np.zeros(len(rows), dtype=bool)
    for column, (formula, is_hard) in enumerate(zip(formulas, hard)):
        difference = np.zeros(len(rows))
        for grounding in ground(formula, space):
            holds = truth(grounding, rows, space)
            difference += holds.astype(np.float64) - np.repeat(truth(grounding, baseline, space), repeat)
            if is_hard:
                forbidden |= ~holds
        nonzero = np.flatnonzero(difference)
        entries.append(nonzero)
        columns.append(np.full(len(nonzero), column))
        values.append(difference[nonzero])
    cat = (lambda parts, dtype: np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype))
    matrix = sparse.csr_matrix((cat(values, np.float64), (cat(entries, np.int64), cat(columns, np.int64))),
                               shape=(len(rows), len(formulas)))
    return Counts(matrix, forbidden)


def frame_counts(formulas: Sequence[Formula], hard: Sequence[bool], evidence: np.ndarray, space: AtomSpace) -> Counts:
    """Per-frame formulas on distinct evidence rows [R, W]: configurations (row, class) in row-major order [R * C]."""
    n_classes = len(space.classes)
    rows, baseline = _configurations(evidence.astype(bool), n_classes)
    return _counts(formulas, hard, space, rows, baseline, n_classes)


def pair_counts(formulas: Sequence[Formula], hard: Sequence[bool], previous: np.ndarray, current: np.ndarray,
                space: AtomSpace) -> Counts:
    """Temporal formulas on distinct consecutive pairs of evidence rows [Q, W] each: configurations
    (pair, class before, class after) in row-major order [Q * C * C]."""
    n_classes = len(space.classes)
    before, before_none = _configurations(previous.astype(bool), n_classes)
    after, after_none = _configurations(current.astype(bool), n_classes)
    pairs = len(previous)
    rows = np.concatenate([np.repeat(before, n_classes, axis=0),
                           np.tile(after.reshape(pairs, n_classes, -1), (1, n_classes, 1)).reshape(pairs * n_classes ** 2, -1)],
                          axis=1)
    baseline = np.concatenate([before_none, after_none], axis=1)
    if not formulas:
        return Counts(sparse.csr_matrix((len(rows), 0)), np.zeros(len(rows), dtype=bool))
    spaces = [space_of(f, space) for f in formulas]
    parts = [_counts([f], [h], s, rows, baseline, n_classes ** 2) for f, h, s in zip(formulas, hard, spaces)]
    return Counts(sparse.hstack([p.matrix for p in parts]).tocsr(), np.logical_or.reduce([p.forbidden for p in parts]))


def read_columns(formulas: Sequence[Formula], columns: Sequence[str]) -> list[int]:
    """The evidence columns the formulas read (all of them if some formula ranges over every word): distinct
    evidence rows need only differ there."""
    return sorted(set().union(*(_read(f, columns, frame=None) for f in formulas)))


def _read(formula: Formula, columns: Sequence[str], frame: str | None) -> set[int]:
    """The columns of the formula's Has atoms (on frame variable ``frame`` only, unless None)."""
    read: set[int] = set()
    for atom in atoms(formula):
        if atom.predicate != EVIDENCE or (frame is not None and atom.args[-1].name != frame):  # type: ignore[union-attr]
            continue
        if isinstance(atom.args[0], Var):
            return set(range(len(columns)))
        read.add(list(columns).index(atom.args[0].value))  # type: ignore[union-attr]
    return read


@dataclass(frozen=True)
class PairColumns:
    """The evidence columns temporal formulas read on the earlier and on the later frame of a pair: distinct
    pairs need only differ there."""

    previous: list[int]
    current: list[int]
    read: list[int]  # both, in column order: the words of the rows ``rows`` rebuilds

    @classmethod
    def of(cls, formulas: Sequence[Formula], columns: Sequence[str]) -> "PairColumns":
        previous, current = set(), set()
        for formula in formulas:
            earlier, later = (term.name for term in next_atom(formula).args)  # type: ignore[union-attr]
            previous |= _read(formula, columns, earlier)
            current |= _read(formula, columns, later)
        return cls(sorted(previous), sorted(current), sorted(previous | current))

    def keys(self, previous: np.ndarray, current: np.ndarray) -> np.ndarray:
        """bool [n, W] x2 -> [n, |previous| + |current|]: what tells pairs apart."""
        return np.concatenate([previous[:, self.previous], current[:, self.current]], axis=1)

    def rows(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The earlier and later frames' rows over ``read`` (columns a frame's formulas do not read: false)."""
        position = {column: i for i, column in enumerate(self.read)}
        previous = np.zeros((len(keys), len(self.read)), dtype=bool)
        current = np.zeros((len(keys), len(self.read)), dtype=bool)
        previous[:, [position[c] for c in self.previous]] = keys[:, :len(self.previous)]
        current[:, [position[c] for c in self.current]] = keys[:, len(self.previous):]
        return previous, current
