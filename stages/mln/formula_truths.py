"""Each formula's truth, one formula at a time, on every class configuration: what explaining a decision reads.

The chain's factors (stages/mln/features.py, factors.py) sum the formulas; an explanation needs them apart. For a
per-frame formula and an evidence row, ``frame_truths`` counts its true groundings with each class (exactly one
class per frame); for a temporal formula and a consecutive pair of rows, ``pair_truths`` counts them with each
(class before, class after). A formula's weight times the difference of its counts between two classes is its
share of the difference between their log-potentials (the count differences of features.py differ from these
counts by a baseline that is the same for every class), and a hard formula forbids the configurations where one
of its groundings is false.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from mlnseq.mln.grounding import AtomSpace, ground, space_of, truth
from mlnseq.mln.syntax import Formula


@dataclass(frozen=True)
class Truths:
    """True groundings [..., F] of each formula on each configuration, and where a grounding is false (for a hard
    formula: the configurations it forbids)."""

    true: np.ndarray  # int64 [..., F]
    broken: np.ndarray  # bool [..., F]: some grounding of the formula is false


def _with_class(evidence: np.ndarray, n_classes: int) -> np.ndarray:
    """[R * C, W + C] each evidence row with each class one-hot, row-major."""
    rows = len(evidence)
    return np.concatenate([np.repeat(evidence.astype(bool), n_classes, axis=0),
                           np.tile(np.eye(n_classes, dtype=bool), (rows, 1))], axis=1)


@lru_cache(maxsize=4096)
def _groundings(formula: Formula, space) -> tuple[Formula, ...]:
    """A formula's groundings in a space, made once: a stream counts truths on each new evidence row."""
    return tuple(ground(formula, space))


def _counted(formulas: Sequence[Formula], rows: np.ndarray, spaces: Sequence) -> Truths:
    """Truths of each formula (evaluated in its own space) on the configuration ``rows``."""
    true = np.zeros((len(rows), len(formulas)), dtype=np.int64)
    broken = np.zeros((len(rows), len(formulas)), dtype=bool)
    for column, (formula, space) in enumerate(zip(formulas, spaces)):
        for grounding in _groundings(formula, space):
            holds = truth(grounding, rows, space)
            true[:, column] += holds
            broken[:, column] |= ~holds
    return Truths(true, broken)


def frame_truths(formulas: Sequence[Formula], evidence: np.ndarray, space: AtomSpace) -> Truths:
    """Per-frame formulas on evidence rows [R, W]: truths [R, C, F]."""
    n_classes = len(space.classes)
    counted = _counted(formulas, _with_class(evidence, n_classes), [space] * len(formulas))
    shape = (len(evidence), n_classes, len(formulas))
    return Truths(counted.true.reshape(shape), counted.broken.reshape(shape))


def pair_truths(formulas: Sequence[Formula], previous: np.ndarray, current: np.ndarray, space: AtomSpace) -> Truths:
    """Temporal formulas on consecutive pairs of evidence rows [Q, W] each: truths [Q, C, C, F] (class before, class
    after)."""
    n_classes, pairs = len(space.classes), len(previous)
    before = np.repeat(_with_class(previous, n_classes), n_classes, axis=0)
    later = _with_class(current, n_classes)
    width = later.shape[1]  # not -1: there may be no pair
    after = np.tile(later.reshape(pairs, n_classes, width), (1, n_classes, 1))
    rows = np.concatenate([before, after.reshape(pairs * n_classes ** 2, width)], axis=1)
    counted = _counted(formulas, rows, [space_of(f, space) for f in formulas])
    shape = (pairs, n_classes, n_classes, len(formulas))
    return Truths(counted.true.reshape(shape), counted.broken.reshape(shape))
