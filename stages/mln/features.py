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

from mlnseq.mln.grounding import EVIDENCE, AtomSpace, PairSpace, ground, next_atom, space_of, truth
from mlnseq.mln.syntax import Formula, Var, atoms


@dataclass(frozen=True)
class Counts:
    """Count differences of each formula on each configuration (the non-zero ones, formula by formula), and the
    configurations hard formulas forbid. Recognising needs numpy alone; the learners take it as a scipy matrix."""

    rows: np.ndarray  # int64 [entries]: each entry's configuration
    columns: np.ndarray  # int64 [entries]: its formula, ascending
    values: np.ndarray  # float64 [entries]
    shape: tuple[int, int]  # [configurations, formulas]
    forbidden: np.ndarray  # bool [configurations]

    def dot(self, weights: np.ndarray) -> np.ndarray:
        """[configurations] the counts times ``weights`` [formulas], summed formula by formula in the order of
        scipy's CSR product (equal to the bit)."""
        total = np.zeros(self.shape[0])
        bounds = np.searchsorted(self.columns, np.arange(self.shape[1] + 1))
        for formula in range(self.shape[1]):
            part = slice(bounds[formula], bounds[formula + 1])
            total[self.rows[part]] += self.values[part] * weights[formula]
        return total

    def sparse(self):  # -> scipy.sparse.csr_matrix [configurations, formulas] float64
        """The counts as a scipy CSR matrix, for the learners (scipy is imported here)."""
        from scipy import sparse

        return sparse.csr_matrix((self.values, (self.rows, self.columns)), shape=self.shape)


def _stack(parts: Sequence[Counts], n_rows: int) -> Counts:
    """The formulas of ``parts`` side by side, in order."""
    offsets = np.cumsum([0, *(part.shape[1] for part in parts)])
    return Counts(np.concatenate([part.rows for part in parts]).astype(np.int64),
                  np.concatenate([part.columns + offset for part, offset in zip(parts, offsets)]).astype(np.int64),
                  np.concatenate([part.values for part in parts]).astype(np.float64), (n_rows, int(offsets[-1])),
                  np.logical_or.reduce([part.forbidden for part in parts]))


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
    return Counts(cat(entries, np.int64), cat(columns, np.int64), cat(values, np.float64), (len(rows), len(formulas)),
                  forbidden)


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
    width = after.shape[1]  # not -1: a recording of one frame has no pair
    after_each = np.tile(after.reshape(pairs, n_classes, width), (1, n_classes, 1)).reshape(pairs * n_classes ** 2,
                                                                                           width)
    rows = np.concatenate([np.repeat(before, n_classes, axis=0), after_each], axis=1)
    baseline = np.concatenate([before_none, after_none], axis=1)
    if not formulas:
        return _counts([], [], space, rows, baseline, n_classes ** 2)
    spaces = [space_of(f, space) for f in formulas]
    return _stack([_counts([f], [h], s, rows, baseline, n_classes ** 2) for f, h, s in zip(formulas, hard, spaces)],
                  len(rows))


def read_columns(formulas: Sequence[Formula], columns: Sequence[str]) -> list[int]:
    """The evidence columns the formulas read (all of them if some formula ranges over every word): distinct
    evidence rows need only differ there."""
    return sorted(set().union(*(_read(f, columns, frame=None) for f in formulas)))


def _read(formula: Formula, columns: Sequence[str], frame: str | None) -> set[int]:
    """The columns of the formula's Has atoms (on frame variable ``frame`` only, unless None)."""
    read: set[int] = set()
    for atom in atoms(formula):
        if atom.predicate != EVIDENCE or (frame is not None
                                          and atom.args[-1].name != frame):  # type: ignore[union-attr]
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
