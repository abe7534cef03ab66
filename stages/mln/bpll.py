"""The native weight learner: pracmln's BPLL objective on the grounded formulas, vectorised.

For every ground atom a of every training frame, BPLL scores log P(a's true value | the other
atoms) = log sigmoid(sum_f w_f * (n_f(a as observed) - n_f(a flipped))), where n_f counts the
true groundings of formula f. With no mutually exclusive blocks each atom is its own block. The
differences n_f(observed) - n_f(flipped) form a sparse matrix D (rows: distinct (frame, atom)
pairs with their multiplicity), so the objective is a weighted logistic loss on D w, maximised
with scipy's BFGS from zero weights and its default gradient tolerance, as pracmln does.
Hard formulas are not optimised: an atom whose flip would break one is determined and drops out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize, sparse

from stages.errors import BadInput
from stages.mln.grounding import AtomSpace, Expanded, atom_indices, ground, truth
from stages.mln.syntax import format_formula


@dataclass(frozen=True)
class Objective:
    """Per distinct (frame, atom) row: the true groundings of each formula with the atom false and
    true (sparse, rows x formulas), the atom's observed value and the row's multiplicity."""

    when_false: sparse.csr_matrix
    when_true: sparse.csr_matrix
    observed: np.ndarray  # bool per row
    counts: np.ndarray
    learned: np.ndarray  # bool per formula


def build_objective(formulas: list[Expanded], rows: np.ndarray, space: AtomSpace) -> Objective:
    """Ground every formula on the distinct training frames (rows of the atom matrix)."""
    unique, counts = np.unique(rows, axis=0, return_counts=True)
    n_unique, n_atoms = unique.shape
    entries: dict[bool, list[list[np.ndarray]]] = {False: [[], [], []], True: [[], [], []]}
    determined = np.zeros(n_unique * n_atoms, dtype=bool)
    for column, item in enumerate(formulas):
        for grounding in ground(item.formula, space):
            observed = truth(grounding, unique, space)
            if item.weight is None and not observed.all():
                frame = int(np.flatnonzero(~observed)[0])
                raise BadInput(
                    f"hard formula {format_formula(item.formula)} is false in a training frame with atoms "
                    f"{_describe(unique[frame], space)}; soften it with a weight"
                )
            for atom in atom_indices(grounding, space):
                flipped = truth(grounding, unique, space, flip=atom)
                if item.weight is None:
                    determined[np.flatnonzero(~flipped) * n_atoms + atom] = True
                    continue
                atom_true = unique[:, atom]
                for value, count in ((False, np.where(atom_true, flipped, observed)),
                                     (True, np.where(atom_true, observed, flipped))):
                    frames = np.flatnonzero(count)
                    entries[value][0].append(frames * n_atoms + atom)
                    entries[value][1].append(np.full(len(frames), column))
                    entries[value][2].append(np.ones(len(frames)))
    matrices = {}
    for value, (row_ids, columns, values) in entries.items():
        cat = (lambda parts, dtype: np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype))
        matrices[value] = sparse.csr_matrix(
            (cat(values, np.float64), (cat(row_ids, np.int64), cat(columns, np.int64))),
            shape=(n_unique * n_atoms, len(formulas)),
        )
    keep = ((matrices[False].getnnz(axis=1) > 0) | (matrices[True].getnnz(axis=1) > 0)) & ~determined
    learned = np.array([item.weight is not None and not item.fixed for item in formulas], dtype=bool)
    return Objective(
        matrices[False][keep], matrices[True][keep], unique.reshape(-1)[keep],
        np.repeat(counts, n_atoms)[keep].astype(np.float64), learned,
    )


def _describe(row: np.ndarray, space: AtomSpace) -> str:
    names = [*space.words, *space.classes]
    return ", ".join(n for n, on in zip(names, row) if on) or "none"


def learn(formulas: list[Expanded], rows: np.ndarray, space: AtomSpace, gtol: float = 1e-5) -> np.ndarray:
    """The BPLL weights of ``formulas`` on the atom matrix ``rows`` (one row per training frame).

    Fixed formulas keep their weight; hard ones get +inf. The probabilities are computed as
    pracmln computes them (exp of each value's sum, then normalised), so that where they saturate
    to 1 in floating point, BFGS takes the same path and stops at the same weights.
    """
    objective = build_objective(formulas, rows, space)
    weights = np.array([0.0 if w.weight is None else w.weight for w in formulas])
    learned = objective.learned
    split = {v: (_compact(m[:, learned]), m[:, ~learned] @ weights[~learned])
             for v, m in ((False, objective.when_false), (True, objective.when_true))}
    observed, counts = objective.observed, objective.counts
    cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    def probabilities(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = w.tobytes()
        if key not in cache:  # BFGS asks for the value and the gradient at the same point
            exp_false = np.exp(split[False][0] @ w + split[False][1])
            exp_true = np.exp(split[True][0] @ w + split[True][1])
            total = exp_false + exp_true
            cache.clear()
            cache[key] = (exp_false / total, exp_true / total)
        return cache[key]

    def negative_pll(w: np.ndarray) -> float:
        p_false, p_true = probabilities(w)
        p_observed = np.where(observed, p_true, p_false)
        return -float(counts @ np.log(np.where(p_observed == 0, 1e-10, p_observed)))

    n_false, n_true = split[False][0], split[True][0]
    observed_counts = n_true.T @ (counts * observed) + n_false.T @ (counts * ~observed)

    def gradient(w: np.ndarray) -> np.ndarray:
        p_false, p_true = probabilities(w)
        return -(observed_counts - n_false.T @ (counts * p_false) - n_true.T @ (counts * p_true))

    if learned.any():
        with np.errstate(over="ignore", invalid="ignore"):
            weights[learned] = optimize.fmin_bfgs(
                negative_pll, np.zeros(int(learned.sum())), fprime=gradient, gtol=gtol, disp=False
            )
    weights[[w.weight is None for w in formulas]] = np.inf
    return weights


def _compact(matrix: sparse.csr_matrix) -> sparse.csr_matrix | np.ndarray:
    """Dense when small: faster products for the few hundred distinct rows of typical data."""
    rows, columns = matrix.shape
    return matrix.toarray() if rows * columns <= 4_000_000 else matrix.tocsr()
