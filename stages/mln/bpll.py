"""The native pseudo-likelihood learner: pracmln's BPLL objective on the grounded formulas, vectorised.

For every ground atom a of every training frame, BPLL scores log P(a's true value | the other
atoms) = log sigmoid(sum_f w_f * (n_f(a as observed) - n_f(a flipped))), where n_f counts the
true groundings of formula f. With no mutually exclusive blocks each atom is its own block. The
differences n_f(observed) - n_f(flipped) form a sparse matrix D (rows: distinct (frame, atom)
pairs with their multiplicity), so the objective is a weighted logistic loss on D w, maximised
from zero weights as pracmln does. Hard formulas are not optimised: an atom whose flip would break
one is determined and drops out.

Temporal formulas (Next): Next is evidence, true exactly between consecutive frames of a chain, so a
frame's atoms are scored given their Markov blanket, which now holds the neighbouring frames' atoms
(the neighbours' classes included): a row is then a distinct (previous frame, frame, next frame)
context, and a temporal grounding counts on the pair (previous, frame) for the frame's atoms in its
later slot and on (frame, next) for those in its earlier slot. Pairs that are not consecutive make a
temporal formula true whatever the atom's value (it must hold when Next is false), so they count
alike for both values and drop out: this is pracmln's DBPLL with Next as the evidence predicate.

Optimiser: scipy's BFGS (pracmln's) while the learned weights are few (``DENSE_LIMIT``), so the paper's
weights come out as pracmln's; L-BFGS beyond, where BFGS's dense n x n updates cost minutes and
hundreds of MB, on the same concave objective.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize, sparse

from mlnseq.mln.blas import one_thread
from mlnseq.mln.distinct_rows import distinct_row_counts
from mlnseq.mln.grounding import AtomSpace, Expanded, atom_indices, ground, is_temporal, space_of, truth


@dataclass(frozen=True)
class Objective:
    """Per distinct (frame, atom) row: the true groundings of each formula with the atom false and
    true (sparse, rows x formulas), the atom's observed value and the row's multiplicity."""

    when_false: sparse.csr_matrix
    when_true: sparse.csr_matrix
    observed: np.ndarray  # bool per row
    counts: np.ndarray
    learned: np.ndarray  # bool per formula


def contexts(rows: np.ndarray, starts: np.ndarray | None) -> np.ndarray:
    """Per frame, [its atoms | the previous frame's | has previous | the next frame's | has next] (zeros where
    missing); just its atoms when ``starts`` is None (per-frame formulas only)."""
    if starts is None:
        return rows
    has_previous = ~np.asarray(starts, dtype=bool)
    has_next = np.r_[has_previous[1:], False]
    previous = np.roll(rows, 1, axis=0) & has_previous[:, None]
    following = np.roll(rows, -1, axis=0) & has_next[:, None]
    return np.concatenate([rows, previous, has_previous[:, None], following, has_next[:, None]], axis=1)


def build_objective(formulas: list[Expanded], rows: np.ndarray, space: AtomSpace,
                    starts: np.ndarray | None = None) -> Objective:
    """Ground every formula on the distinct training frames (rows of the atom matrix), with their neighbours
    in the chains that ``starts`` cuts (only when some formula is temporal)."""
    temporal = [is_temporal(item.formula) for item in formulas]
    unique, counts = distinct_row_counts(contexts(rows, starts if any(temporal) else None))
    n_unique, n_atoms = len(unique), space.size
    current = unique[:, :n_atoms]
    # where a temporal formula sees the frame: (pair rows, which contexts, the slot of the frame's atoms)
    sides = [] if not any(temporal) else [
        (np.concatenate([unique[:, n_atoms:2 * n_atoms], current], axis=1), unique[:, 2 * n_atoms], n_atoms),
        (np.concatenate([current, unique[:, 2 * n_atoms + 1:3 * n_atoms + 1]], axis=1), unique[:, -1], 0),
    ]
    entries: dict[bool, list[list[np.ndarray]]] = {False: [[], [], []], True: [[], [], []]}
    determined = np.zeros(n_unique * n_atoms, dtype=bool)

    def add(column: int, hard: bool, grounding, pair_rows: np.ndarray, where: np.ndarray, pair_space,
            slot: int) -> None:
        observed = truth(grounding, pair_rows, pair_space)
        for index in atom_indices(grounding, pair_space):
            if not slot <= index < slot + n_atoms:
                continue  # an atom of the other frame of the pair
            atom = index - slot
            flipped = truth(grounding, pair_rows, pair_space, flip=index)
            if hard:
                determined[np.flatnonzero(~flipped & where) * n_atoms + atom] = True
                continue
            atom_true = pair_rows[:, index]
            for value, count in ((False, np.where(atom_true, flipped, observed)),
                                 (True, np.where(atom_true, observed, flipped))):
                frames = np.flatnonzero(count & where)
                entries[value][0].append(frames * n_atoms + atom)
                entries[value][1].append(np.full(len(frames), column))
                entries[value][2].append(np.ones(len(frames)))

    everywhere = np.ones(n_unique, dtype=bool)
    for column, (item, is_temporal_formula) in enumerate(zip(formulas, temporal)):
        formula_space = space_of(item.formula, space)
        for grounding in ground(item.formula, formula_space):
            if not is_temporal_formula:
                add(column, item.weight is None, grounding, current, everywhere, space, 0)
                continue
            for pair_rows, where, slot in sides:
                add(column, item.weight is None, grounding, pair_rows, where, formula_space, slot)
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
        matrices[False][keep], matrices[True][keep], current.reshape(-1)[keep],
        np.repeat(counts, n_atoms)[keep].astype(np.float64), learned,
    )


DENSE_LIMIT = 500  # learned weights up to which BFGS (pracmln's optimiser) is used


def learn(formulas: list[Expanded], rows: np.ndarray, space: AtomSpace, starts: np.ndarray | None = None,
          l2: float = 0.0, gtol: float = 1e-5, optimiser: str | None = None) -> np.ndarray:
    """The BPLL weights of ``formulas`` on the atom matrix ``rows`` (one row per training frame; chains cut
    where ``starts`` is True), maximising PLL - l2/2 |w|^2 over the learned weights. ``optimiser``: "bfgs" or
    "l-bfgs"; None chooses by the number of learned weights (``DENSE_LIMIT``).

    Fixed formulas keep their weight; hard ones get +inf. The probabilities are computed as
    pracmln computes them (exp of each value's sum, then normalised), so that where they saturate
    to 1 in floating point, BFGS takes the same path and stops at the same weights.
    """
    objective = build_objective(formulas, rows, space, starts)
    weights = np.array([0.0 if w.weight is None else w.weight for w in formulas])
    learned = objective.learned
    split = {v: (_compact(m[:, learned]), m[:, ~learned] @ weights[~learned])
             for v, m in ((False, objective.when_false), (True, objective.when_true))}
    observed, counts = objective.observed, objective.counts
    cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    def probabilities(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = w.tobytes()
        if key not in cache:  # the optimiser asks for the value and the gradient at the same point
            exp_false = np.exp(split[False][0] @ w + split[False][1])
            exp_true = np.exp(split[True][0] @ w + split[True][1])
            total = exp_false + exp_true
            cache.clear()
            cache[key] = (exp_false / total, exp_true / total)
        return cache[key]

    def negative_pll(w: np.ndarray) -> float:
        p_false, p_true = probabilities(w)
        p_observed = np.where(observed, p_true, p_false)
        return -float(counts @ np.log(np.where(p_observed == 0, 1e-10, p_observed))) + 0.5 * l2 * float(w @ w)

    n_false, n_true = split[False][0], split[True][0]
    observed_counts = n_true.T @ (counts * observed) + n_false.T @ (counts * ~observed)

    def gradient(w: np.ndarray) -> np.ndarray:
        p_false, p_true = probabilities(w)
        return -(observed_counts - n_false.T @ (counts * p_false) - n_true.T @ (counts * p_true)) + l2 * w

    n_learned = int(learned.sum())
    if n_learned:
        with np.errstate(over="ignore", invalid="ignore"), one_thread():
            if (optimiser or ("bfgs" if n_learned <= DENSE_LIMIT else "l-bfgs")) == "bfgs":
                weights[learned] = optimize.fmin_bfgs(
                    negative_pll, np.zeros(n_learned), fprime=gradient, gtol=gtol, disp=False)
            else:
                weights[learned] = optimize.minimize(
                    negative_pll, np.zeros(n_learned), jac=gradient, method="L-BFGS-B",
                    options={"gtol": gtol, "ftol": 0.0, "maxiter": 15000, "maxcor": 20}).x
    weights[[w.weight is None for w in formulas]] = np.inf
    return weights


def log_pseudo_likelihood(objective: Objective, weights: np.ndarray) -> float:
    """The PLL of ``weights`` (finite, every formula's) on a built objective, computed without overflow."""
    when_false, when_true = objective.when_false @ weights, objective.when_true @ weights
    observed = np.where(objective.observed, when_true, when_false)
    return float(objective.counts @ (observed - np.logaddexp(when_false, when_true)))


def _compact(matrix: sparse.csr_matrix) -> sparse.csr_matrix | np.ndarray:
    """Dense when small: faster products for the few hundred distinct rows of typical data."""
    rows, columns = matrix.shape
    return matrix.toarray() if rows * columns <= 4_000_000 else matrix.tocsr()
