"""The MLN's factors for chain inference, from a weights.parquet table.

Per-frame formulas give each frame's unary log-potentials [C] (the class scores of
``mlnseq.mln.classifier``, with -inf where a hard formula forbids the class); temporal formulas give
the pairwise log-potentials [C, C] between a frame and the next (-inf where a hard rule forbids the
transition). Both are computed once per distinct evidence row (pair of rows) and cached, so a live
stream may ask for one frame at a time.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import polars as pl

from mlnseq.catalog.errors import BadInput
from mlnseq.mln.chain import ChainFactors
from mlnseq.mln.distinct_rows import distinct_rows
from mlnseq.mln.features import PairColumns, frame_counts, pair_counts, read_columns
from mlnseq.mln.grounding import EVIDENCE, AtomSpace, class_aliases, class_constant, is_temporal, rename_classes
from mlnseq.mln.syntax import Const, Formula, MLNSyntaxError, atoms, parse_formula


@dataclass(frozen=True)
class LearnedFormula:
    """One row of weights.parquet, parsed."""

    text: str
    formula: Formula
    weight: float  # +inf when hard
    hard: bool
    temporal: bool


def parse_weights(weights: pl.DataFrame, columns: Sequence[str], classes: int | Sequence[str]) -> list[LearnedFormula]:
    """The formulas of a weights table that count (non-zero or hard), checked against the evidence columns.
    ``classes``: the frames' class names in label order (a formula may name a class so, or as the paper's
    ``C<k>``), or their number (``C<k>`` only)."""
    n_classes = classes if isinstance(classes, int) else len(classes)
    aliases = class_aliases([class_constant(k) for k in range(classes)] if isinstance(classes, int) else classes)
    space = frame_space(columns, n_classes)
    parsed = []
    for text, weight, hard in weights.select("formula", "weight", "hard").iter_rows():
        if weight == 0.0 and not hard:
            continue
        try:
            formula = rename_classes(parse_formula(text, "weights.parquet"), aliases)
        except MLNSyntaxError as error:
            raise BadInput(f"{error}; rerun `mlnseq learn-weights`") from error
        for atom in atoms(formula):
            if isinstance(atom.args[0], Const) and not space.contains(atom):
                raise BadInput(f"weights.parquet formula {text} uses {atom.args[0].value}, which "
                               f"{'predicates.parquet lacks' if atom.predicate == EVIDENCE else 'is not a class'}; "
                               "rerun `mlnseq learn-weights`")
        parsed.append(LearnedFormula(text, formula, float("inf") if hard else float(weight), bool(hard),
                                     is_temporal(formula)))
    return parsed


def frame_space(columns: Sequence[str], n_classes: int) -> AtomSpace:
    return AtomSpace(tuple(columns), tuple(class_constant(k) for k in range(n_classes)))


def _scores(counts, formulas: Sequence[LearnedFormula], shape: tuple[int, ...],
            hard_weight: float | None) -> np.ndarray:
    weights = np.array([0.0 if f.hard and hard_weight is None else (hard_weight if f.hard else f.weight)
                        for f in formulas])
    scores = counts.dot(weights).reshape(shape)
    if hard_weight is None:
        scores[counts.forbidden.reshape(shape)] = -np.inf
    return scores


def frame_scores(formulas: Sequence[LearnedFormula], evidence: np.ndarray, columns: Sequence[str], n_classes: int,
                 hard_weight: float | None = None) -> np.ndarray:
    """[R, C] the per-frame formulas' log-potential of each class on each evidence row; a hard formula
    forbids (-inf), or with ``hard_weight`` counts with that weight (the paper's scores)."""
    space = frame_space(columns, n_classes)
    counts = frame_counts([f.formula for f in formulas], [f.hard for f in formulas], evidence, space)
    return _scores(counts, formulas, (len(evidence), n_classes), hard_weight)


def pair_scores(formulas: Sequence[LearnedFormula], previous: np.ndarray, current: np.ndarray,
                columns: Sequence[str], n_classes: int) -> np.ndarray:
    """[Q, C, C] the temporal formulas' log-potential of each (class before, class after) on each pair of rows."""
    space = frame_space(columns, n_classes)
    counts = pair_counts([f.formula for f in formulas], [f.hard for f in formulas], previous, current, space)
    return _scores(counts, formulas, (len(previous), n_classes, n_classes), None)


class MLNFactors:
    """The unary and pairwise log-potentials of an MLN's learned formulas, cached per distinct evidence."""

    def __init__(self, formulas: Sequence[LearnedFormula], columns: Sequence[str], n_classes: int):
        self.n_classes = n_classes
        self._per_frame = [f for f in formulas if not f.temporal]
        self._between = [f for f in formulas if f.temporal]
        self.temporal = bool(self._between)
        self._frame_columns = read_columns([f.formula for f in self._per_frame], columns)
        self._pair_columns = PairColumns.of([f.formula for f in self._between], columns)
        self._frame_names = [columns[i] for i in self._frame_columns]
        self._pair_names = [columns[i] for i in self._pair_columns.read]
        self._unary: dict[bytes, np.ndarray] = {}
        self._pairwise: dict[bytes, np.ndarray] = {}

    @classmethod
    def from_weights(cls, weights: pl.DataFrame, columns: Sequence[str], classes: int | Sequence[str]) -> "MLNFactors":
        """weights: a weights.parquet table; columns: the evidence columns, in the order of the arrays passed
        later; refuses a formula over a column it lacks (BadInput)."""
        n_classes = classes if isinstance(classes, int) else len(classes)
        return cls(parse_weights(weights, columns, classes), list(columns), n_classes)

    def unary(self, evidence: np.ndarray) -> np.ndarray:
        """bool [T, W] -> [T, C] the per-frame formulas' log-potentials (-inf: a hard formula forbids)."""
        evidence = np.asarray(evidence, dtype=bool)
        if len(evidence) == 1:  # a live stream: one frame at a time
            return self._one(self._unary, evidence[0, self._frame_columns], self._frame_scores)
        return self._many(self._unary, evidence[:, self._frame_columns], self._frame_scores)

    def pairwise(self, previous: np.ndarray, current: np.ndarray) -> np.ndarray:
        """bool [T, W] x2 -> [T, C, C] the temporal formulas' log-potentials of (class at t-1, class at t)."""
        keys = self._pair_columns.keys(np.asarray(previous, dtype=bool), np.asarray(current, dtype=bool))
        if len(keys) == 1:
            return self._one(self._pairwise, keys[0], self._pair_scores)
        return self._many(self._pairwise, keys, self._pair_scores)

    def _frame_scores(self, rows: np.ndarray) -> np.ndarray:
        return frame_scores(self._per_frame, rows, self._frame_names, self.n_classes)

    def _pair_scores(self, keys: np.ndarray) -> np.ndarray:
        return pair_scores(self._between, *self._pair_columns.rows(keys), self._pair_names, self.n_classes)

    def chain(self, evidence: np.ndarray, starts: np.ndarray, per_frame: bool = True) -> ChainFactors:
        """The chain factors of frames whose chains start where ``starts`` (bool [T]) is True (frame 0 always).
        per_frame=False: unary zeros (only the temporal factors). With no temporal formula the pairwise
        factors are all zero (uniform transitions)."""
        evidence = np.asarray(evidence, dtype=bool)
        n_frames = len(evidence)
        unary = self.unary(evidence) if per_frame else np.zeros((n_frames, self.n_classes))
        starts = np.asarray(starts, dtype=bool).copy()
        if n_frames:
            starts[0] = True
        joined = np.flatnonzero(~starts)
        distinct, inverse = distinct_rows(self._pair_columns.keys(evidence[joined - 1], evidence[joined]))
        pairwise = self._many(self._pairwise, distinct, self._pair_scores)
        link = np.full(n_frames, -1, dtype=np.int64)
        link[joined] = inverse
        return ChainFactors(unary, pairwise, link)

    @staticmethod
    def _one(cache: dict[bytes, np.ndarray], key: np.ndarray, compute) -> np.ndarray:
        name = key.tobytes()
        values = cache.get(name)
        if values is None:
            values = cache[name] = compute(key[None])[0]
        return values[None].copy()

    @staticmethod
    def _many(cache: dict[bytes, np.ndarray], keys: np.ndarray, compute) -> np.ndarray:
        distinct, inverse = distinct_rows(keys)
        missing = [i for i, row in enumerate(distinct) if row.tobytes() not in cache]
        if missing:
            for row, values in zip(distinct[missing], compute(distinct[missing])):
                cache[row.tobytes()] = values
        if not len(distinct):
            return compute(distinct)
        return np.stack([cache[row.tobytes()] for row in distinct])[inverse]
