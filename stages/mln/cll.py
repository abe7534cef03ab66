"""The native conditional-likelihood learner: each chain's class sequence given its evidence, exactly.

With one class per frame (one-hot Topic atoms) and formulas over one frame or two consecutive ones,
the MLN conditioned on the evidence is a linear-chain CRF: per-frame formulas give unary
log-potentials, temporal ones pairwise log-potentials, both linear in the weights
(``mlnseq.mln.features``). The objective

    CLL(w) - l2/2 |w|^2,   CLL(w) = sum over chains of log p(y_chain | evidence_chain; w)

is concave; its gradient is the observed minus the expected formula counts, the expectations coming
from forward-backward marginals (``mlnseq.mln.chain_moments``), and it is maximised with (L-)BFGS from zero
weights (see ``learn``). Without the penalty an optimum may lie at infinity (a transition never seen in training gets
weight -> -inf), hence ``l2`` (a Gaussian prior of variance 1/l2 on each learned weight).

``DEFAULT_L2`` was chosen on training splits only (benchmarks/bench_learn_weights.py prints this table,
"cll's L2 penalty on held-out training frames"): learn examples/temporal.mln (the paper's template plus
transitions) on the first 80 % of a training split (DESK: 1,124 of its one training episode's 1,405 frames;
a simulated Fetch collection of 40 episodes, all training, seed 3: 32 episodes; the Fetch paper split, the
first 126 frames of a collection: 100 frames) and score the conditional log-likelihood per frame of the
remaining 20 % (281 frames, 8 episodes, 26 frames):

    l2        0.001    0.003    0.01     0.03     0.1      0.3      1        3
    DESK     -0.0780  -0.0794  -0.0801  -0.0814  -0.0840  -0.0889  -0.1007  -0.1262
    Fetch 40 -0.1309  -0.1310  -0.1311  -0.1313  -0.1322  -0.1343  -0.1404  -0.1538
    Fetch 126-0.2579  -0.2327  -0.2089  -0.1953  -0.1907  -0.1992  -0.2394  -0.3338
    mean     -0.1556  -0.1477  -0.1400  -0.1360  -0.1356  -0.1408  -0.1602  -0.2046

The mean is best at 0.1 (small data needs the prior; large data hardly cares). MLN-alone Viterbi frame
accuracy on the same held-out frames at 0.1: DESK 0.726, Fetch 40 0.718, Fetch 126 0.846 (at 0.001:
0.790, 0.718, 0.885).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy import linalg, optimize, sparse

from mlnseq.mln import chain, chain_moments
from mlnseq.mln.chain_scan import Repeats
from mlnseq.mln.blas import one_thread
from mlnseq.mln.bpll import DENSE_LIMIT
from mlnseq.mln.distinct_rows import distinct_rows
from mlnseq.mln.features import PairColumns, frame_counts, pair_counts, read_columns
from mlnseq.mln.grounding import AtomSpace, Expanded, is_temporal

DEFAULT_L2 = 0.1


@dataclass(frozen=True)
class ChainData:
    """The training chains as the CRF sees them: distinct evidence rows and pairs, and each frame's."""

    labels: np.ndarray  # [T] class per frame
    row: np.ndarray  # [T] distinct evidence row of each frame
    link: np.ndarray  # [T] distinct consecutive pair ending at each frame, -1 at chain starts
    n_rows: int
    n_pairs: int


def chain_data(evidence: np.ndarray, labels: np.ndarray, starts: np.ndarray, frame_columns: list[int],
               pair_columns: PairColumns) -> tuple[ChainData, np.ndarray, np.ndarray]:
    """The chains, the distinct evidence rows [R, len(frame_columns)] and the distinct consecutive pairs (their
    keys, ``PairColumns.keys``) they are made of: rows and pairs told apart only by the columns formulas read."""
    evidence = np.asarray(evidence, dtype=bool)
    starts = np.asarray(starts, dtype=bool).copy()
    starts[0] = True
    rows, row = distinct_rows(evidence[:, frame_columns])
    joined = np.flatnonzero(~starts)
    pairs, pair = distinct_rows(pair_columns.keys(evidence[joined - 1], evidence[joined]))
    link = np.full(len(evidence), -1, dtype=np.int64)
    link[joined] = pair
    data = ChainData(np.asarray(labels, dtype=np.int64), row, link, len(rows), len(pairs))
    return data, rows, pairs


class Objective:
    """CLL - l2/2 |w|^2 of the learned weights, and its gradient, on the training chains."""

    def __init__(self, formulas: list[Expanded], evidence: np.ndarray, labels: np.ndarray, starts: np.ndarray,
                 space: AtomSpace, l2: float):
        temporal = np.array([is_temporal(f.formula) for f in formulas], dtype=bool)
        per_frame = [f.formula for f, t in zip(formulas, temporal) if not t]
        between = [f.formula for f, t in zip(formulas, temporal) if t]
        frame_columns, pair_columns = read_columns(per_frame, space.words), PairColumns.of(between, space.words)
        self.data, rows, pairs = chain_data(evidence, labels, starts, frame_columns, pair_columns)
        self.n_classes = n_classes = len(space.classes)
        self.l2 = l2
        hard = np.array([f.weight is None for f in formulas], dtype=bool)
        self.learned = np.array([f.weight is not None and not f.fixed for f in formulas], dtype=bool)
        self.weights = np.array([0.0 if f.weight is None else f.weight for f in formulas])
        self.temporal = temporal
        unary = frame_counts(per_frame, hard[~temporal].tolist(), rows, _subspace(space, frame_columns))
        pairwise = pair_counts(between, hard[temporal].tolist(), *pair_columns.rows(pairs),
                               _subspace(space, pair_columns.read))
        self.unary_counts, self.pairwise_counts = unary.sparse(), pairwise.sparse()
        self.unary_forbidden = unary.forbidden.reshape(self.data.n_rows, n_classes)
        self.pairwise_forbidden = pairwise.forbidden.reshape(self.data.n_pairs, n_classes, n_classes)
        data = self.data
        frames = len(data.labels)
        self.frames_of_row = sparse.csr_matrix((np.ones(frames), (data.row, np.arange(frames))),
                                               shape=(data.n_rows, frames))
        joined = np.flatnonzero(data.link >= 0)
        self.observed = np.zeros(len(formulas))
        self.observed[~temporal] = self.unary_counts.T @ np.bincount(
            data.row * n_classes + data.labels, minlength=data.n_rows * n_classes)
        self.observed[temporal] = self.pairwise_counts.T @ np.bincount(
            (data.link[joined] * n_classes + data.labels[joined - 1]) * n_classes + data.labels[joined],
            minlength=data.n_pairs * n_classes ** 2)
        per_formula = np.argsort(np.concatenate([np.flatnonzero(~temporal), np.flatnonzero(temporal)]))
        self.counts = sparse.block_diag([self.unary_counts, self.pairwise_counts]).tocsc()[:, per_formula][
            :, self.learned]
        self.repeats = Repeats.of(data.row, data.link)
        self.evaluations = 0

    def factors(self, weights: np.ndarray) -> chain.ChainFactors:
        """The chain factors of the training frames under ``weights`` (all formulas; hard ones unused)."""
        n_classes, data = self.n_classes, self.data
        unary = (self.unary_counts @ np.where(np.isinf(weights[~self.temporal]), 0.0, weights[~self.temporal])
                 ).reshape(data.n_rows, n_classes)
        pairwise = (self.pairwise_counts @ np.where(np.isinf(weights[self.temporal]), 0.0, weights[self.temporal])
                    ).reshape(data.n_pairs, n_classes, n_classes)
        unary[self.unary_forbidden] = -np.inf
        pairwise[self.pairwise_forbidden] = -np.inf
        return chain.ChainFactors(unary[data.row], pairwise, data.link)

    def full(self, learned: np.ndarray) -> np.ndarray:
        weights = self.weights.copy()
        weights[self.learned] = learned
        return weights

    def __call__(self, learned: np.ndarray) -> tuple[float, np.ndarray]:
        """(-(CLL - l2/2 |w|^2), its gradient) over the learned weights, both per training frame."""
        self.evaluations += 1
        weights = self.full(learned)
        expectations = chain_moments.expectations(self.factors(weights), self.repeats)
        finite = np.where(np.isinf(weights), 0.0, weights)
        expected = np.zeros(len(weights))
        expected[~self.temporal] = self.unary_counts.T @ np.asarray(self.frames_of_row @ expectations.unary).reshape(-1)
        expected[self.temporal] = self.pairwise_counts.T @ expectations.pairwise.reshape(-1)
        value = float(self.observed @ finite) - expectations.log_z - 0.5 * self.l2 * float(learned @ learned)
        gradient = (self.observed - expected)[self.learned] - self.l2 * learned
        frames = len(self.data.labels)
        return -value / frames, -gradient / frames

    def hessian(self, learned: np.ndarray) -> np.ndarray:
        """[L, L] the Hessian of -(CLL - l2/2 |w|^2) per frame over the learned weights at ``learned``: the covariance
        of the formula counts under the chains' distribution (``chain_moments.count_covariance``), plus l2."""
        covariance = chain_moments.count_covariance(self.factors(self.full(learned)), self.data.row, self.data.n_rows,
                                            self.repeats)
        counts = self.counts.toarray()
        return (counts.T @ covariance @ counts + self.l2 * np.eye(len(learned))) / len(self.data.labels)

    def curvature(self) -> np.ndarray:
        """[F, F] the Hessian of -(CLL - l2/2 |w|^2) per frame at w = 0 if frames were independent (uniform
        classes): sum over frames of the covariance of their formula counts, plus l2. It holds the formulas'
        collinearity (the paper's template repeats a class bias once per predicate group), which is what makes
        plain L-BFGS crawl; optimising in the coordinates it whitens removes that."""
        n_classes, data = self.n_classes, self.data
        frames = np.bincount(data.row, minlength=data.n_rows).astype(np.float64)
        pairs = np.bincount(data.link[data.link >= 0], minlength=data.n_pairs).astype(np.float64)
        matrix = np.zeros((len(self.weights), len(self.weights)))
        for mask, counts, weights, size in ((~self.temporal, self.unary_counts, frames, n_classes),
                                            (self.temporal, self.pairwise_counts, pairs, n_classes ** 2)):
            if not mask.any() or not len(weights):
                continue
            per_configuration = sparse.diags(np.repeat(weights, size)) @ counts
            summed = sparse.csr_matrix((np.ones(counts.shape[0]), (np.repeat(np.arange(len(weights)), size),
                                                                      np.arange(counts.shape[0]))))
            totals = summed @ counts  # [rows, F]: each row's counts summed over its configurations
            block = (counts.T @ per_configuration).toarray() / size \
                - (totals.T @ sparse.diags(weights) @ totals).toarray() / size ** 2
            matrix[np.ix_(mask, mask)] = block
        learned = matrix[np.ix_(self.learned, self.learned)] + self.l2 * np.eye(int(self.learned.sum()))
        return learned / len(data.labels)


def _subspace(space: AtomSpace, columns: list[int]) -> AtomSpace:
    return AtomSpace(tuple(space.words[i] for i in columns), space.classes)


REFRESH = (35, 10)  # BFGS iterations after which the metric is renewed with the exact Hessian at the point reached
METRIC_FRAMES = 20_000  # the exact Hessian (a metric only) is measured on at most this many frames: whole chains


def metric_sample(starts: np.ndarray, most: int = METRIC_FRAMES) -> np.ndarray | None:
    """The rows of whole chains spread evenly (every k-th chain) that hold at most about ``most`` frames, or None
    where all of them do. The metric only shapes BFGS's steps: the optimum and the stopping rule stay the whole
    data's, and at 350,000 frames the exact Hessian was two thirds of learning."""
    starts = np.asarray(starts, dtype=bool).copy()
    starts[0] = True
    if len(starts) <= most:
        return None
    chain = np.cumsum(starts) - 1
    rows = np.flatnonzero(chain % int(np.ceil(len(starts) / most)) == 0)
    return rows if len(rows) < len(starts) else None  # one long chain: all of it


def learn(formulas: list[Expanded], evidence: np.ndarray, labels: np.ndarray, starts: np.ndarray,
          space: AtomSpace, l2: float = DEFAULT_L2, gtol: float = 1e-6, ftol: float = 1e-8,
          initial: np.ndarray | None = None, metric_frames: int = METRIC_FRAMES) -> np.ndarray:
    """The weights maximising CLL - l2/2 |w|^2 on the chains of ``evidence`` (bool [T, W] over
    ``space.words``) with classes ``labels`` (indices into ``space.classes``), cut where ``starts``.
    Fixed formulas keep their weight; hard ones get +inf (the labels must satisfy them).

    BFGS (up to ``bpll.DENSE_LIMIT`` learned weights), else L-BFGS, in coordinates whitened by a metric: first
    ``curvature`` (the Hessian at zero weights); BFGS then renews it with the exact Hessian after ``REFRESH``
    iterations, because the curvature changes by orders of magnitude as the chains' marginals sharpen (from the
    first metric BFGS alone needs about 400 evaluations on all DESK frames, with the renewals about 60). Each run
    stops when the largest entry of the whitened gradient per frame falls below ``gtol`` (L-BFGS also when an
    iteration improves the objective per frame by less than ``ftol``, relatively); in the exact Hessian's
    coordinates that is a bound on the Newton step. Over ``metric_frames`` frames the exact Hessian is measured on
    whole chains drawn evenly (:func:`metric_sample`). ``initial``: a starting point for every weight (hard ones
    ignored) near the optimum, where BFGS starts from the exact Hessian (a search that adds a few formulas)."""
    objective = Objective(formulas, evidence, labels, starts, space, l2)
    sample = metric_sample(starts, metric_frames)

    @functools.cache
    def measured() -> Objective:
        """The objective the exact Hessian is measured on: this one, or its chains drawn (made once, when needed)."""
        if sample is None:
            return objective
        return Objective(formulas, np.asarray(evidence)[sample], np.asarray(labels)[sample],
                         np.asarray(starts)[sample], space, l2)

    weights = objective.weights.copy()
    n_learned = int(objective.learned.sum())
    if n_learned:
        dense = n_learned <= DENSE_LIMIT
        if dense:
            method, options, runs = "BFGS", {"gtol": gtol}, (*REFRESH, 5000)
        else:
            method, options, runs = "L-BFGS-B", {"gtol": gtol, "ftol": ftol, "maxcor": 20}, (5000,)
        if initial is None:
            learned, metric = np.zeros(n_learned), objective.curvature()
        else:  # near the optimum already (a search's previous set): the exact Hessian there
            learned = np.asarray(initial, dtype=np.float64)[objective.learned].copy()
            metric, runs = measured().hessian(learned), runs[1:]
        with one_thread():
            for run, iterations in enumerate(runs):
                if run:
                    metric = measured().hessian(learned)
                # l2 = 0: keep it definite
                metric += 1e-9 * max(np.trace(metric) / n_learned, 1e-12) * np.eye(n_learned)
                factor = linalg.cholesky(metric, lower=True)  # learned + factor^-T z

                def whitened(z: np.ndarray) -> tuple[float, np.ndarray]:
                    value, gradient = objective(learned + linalg.solve_triangular(factor, z, lower=True, trans="T"))
                    return value, linalg.solve_triangular(factor, gradient, lower=True)

                result = optimize.minimize(whitened, np.zeros(n_learned), jac=True, method=method,
                                           options={**options, "maxiter": iterations})
                learned = learned + linalg.solve_triangular(factor, result.x, lower=True, trans="T")
                if result.status != 1:  # converged (or no further progress possible), not out of iterations
                    break
        weights[objective.learned] = learned
    weights[[f.weight is None for f in formulas]] = np.inf
    return weights


def network_weight(factors: chain.ChainFactors, log_p_network: np.ndarray, labels: np.ndarray,
                   l2: float = DEFAULT_L2) -> float:
    """The network factor's weight w >= 0 maximising CLL - l2/2 w^2 of the chains whose per-frame log-potentials
    are ``factors.unary + w * log_p_network`` (the network's log-probabilities as one more per-frame feature,
    the MLN's weights as given): concave in w; its gradient is the observed minus the expected network
    log-probability of the true classes. Pass out-of-fold log-probabilities: on the frames a network was
    trained on it is overconfident, and the weight learned there is far too large."""
    from dataclasses import replace

    log_p = np.asarray(log_p_network, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    observed = float(log_p[np.arange(len(labels)), labels].sum())
    finite = np.where(np.isfinite(factors.unary), log_p, 0.0)  # a forbidden class has marginal 0
    frames = len(labels)

    def objective(w: np.ndarray) -> tuple[float, np.ndarray]:
        weighted = replace(factors, unary=factors.unary + w[0] * log_p)
        expected = chain_moments.expectations(weighted)
        value = chain.path_score(weighted, labels) - expected.log_z - 0.5 * l2 * w[0] ** 2
        gradient = observed - float((expected.unary * finite).sum()) - l2 * w[0]
        return -value / frames, np.array([-gradient / frames])

    with one_thread():
        result = optimize.minimize(objective, np.array([1.0]), jac=True, method="L-BFGS-B", bounds=[(0.0, None)],
                                   options={"gtol": 1e-7, "ftol": 1e-10})
    return float(result.x[0])
