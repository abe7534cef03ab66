"""CLL learning: its gradient, and learned transitions that decode held-out training frames better."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog import artifacts
from mlnseq import binarize
from mlnseq import learn_weights as stage
from mlnseq.formulas import DEFAULT_SPEC, formulas_for, read_spec
from mlnseq.mln import chain, cll
from mlnseq.mln.factors import MLNFactors
from mlnseq.mln.grounding import AtomSpace, class_constant, expand_templates
from mlnseq.mln.published_codes import desk_predicates
from mlnseq.mln.syntax import parse_mln

TEMPORAL = Path(__file__).resolve().parents[3] / "examples" / "temporal.mln"

MIXED = """Has(word, page)
Topic(class, page)
Next(page, page)
0.0 Has(+w, p) => Topic(+c, p)
0.0 Topic(+c1, p) ^ Next(p, q) => Topic(+c2, q)
0.0 Topic(+c1, p) ^ Next(p, q) ^ Has("left_gripper_closing", q) => Topic(+c2, q)
0.7 Has("arm_distance_static", p) => Topic("C3", p)
Topic("C0", p) ^ Next(p, q) => !Topic("C6", q).
"""


def held_out(table: pl.DataFrame, by_episode: bool) -> pl.DataFrame:
    """The training split with its last 20 % (of episodes, or of frames) relabelled 'test'."""
    train = table.filter(pl.col("split") == "train")
    if by_episode:
        episodes = train["episode"].unique(maintain_order=True).to_list()
        fit = train["episode"].is_in(episodes[: int(round(0.8 * len(episodes)))])
    else:
        fit = pl.Series(np.arange(train.height) < int(0.8 * train.height))
    return train.with_columns(pl.when(fit).then(pl.lit("train")).otherwise(pl.lit("test")).alias("split"))


def mixed_objective(shared_data: Path, frames: int, l2: float) -> tuple[cll.Objective, object]:
    """The CLL objective of MIXED on the first ``frames`` DESK training frames, and their training data."""
    training = stage.training_data(desk_predicates(shared_data, train_limit=frames)[0], 7)
    expanded, _, _ = expand_templates(parse_mln(MIXED, "mixed.mln").formulas, training.space)
    states = AtomSpace(training.space.words, tuple(class_constant(k) for k in range(7)))
    return cll.Objective(expanded, training.evidence, training.labels, training.starts, states, l2=l2), training


def test_gradient_matches_finite_differences(shared_data: Path) -> None:
    objective, _ = mixed_objective(shared_data, 200, l2=0.1)
    assert objective.temporal.any() and (~objective.temporal).any() and (~objective.learned).sum() == 2
    rng = np.random.default_rng(0)
    weights = rng.normal(size=int(objective.learned.sum()))
    value, gradient = objective(weights)
    assert np.isfinite(value)
    for index in rng.choice(len(weights), size=12, replace=False):
        step = np.zeros_like(weights)
        step[index] = 1e-5
        numeric = (objective(weights + step)[0] - objective(weights - step)[0]) / 2e-5
        assert gradient[index] == pytest.approx(numeric, rel=1e-5, abs=1e-8)


def test_hessian_matches_finite_differences_of_the_gradient(shared_data: Path) -> None:
    objective, _ = mixed_objective(shared_data, 150, l2=0.1)
    weights = np.random.default_rng(2).normal(size=int(objective.learned.sum()))
    hessian = objective.hessian(weights)
    assert np.allclose(hessian, hessian.T) and np.linalg.eigvalsh(hessian).min() > 0
    for index in np.random.default_rng(3).choice(len(weights), size=10, replace=False):
        step = np.zeros_like(weights)
        step[index] = 1e-5
        numeric = (objective(weights + step)[1] - objective(weights - step)[1]) / 2e-5
        assert hessian[:, index] == pytest.approx(numeric, rel=1e-4, abs=1e-7)


def test_learned_weights_are_the_optimum(shared_data: Path) -> None:
    """At the learned weights the Newton step is negligible (the optimum is within 2e-4 in every weight, to first
    order) and so is the objective left to gain (the Newton decrement, per frame)."""
    table = desk_predicates(shared_data)[0]
    training = stage.training_data(table, 7)
    mln = read_spec(TEMPORAL)
    expanded, _, _ = expand_templates(mln.formulas, training.space)
    states = AtomSpace(training.space.words, tuple(class_constant(k) for k in range(7)))
    weights = cll.learn(expanded, training.evidence, training.labels, training.starts, states)
    objective = cll.Objective(expanded, training.evidence, training.labels, training.starts, states, cll.DEFAULT_L2)
    _, gradient = objective(weights)
    newton = np.linalg.solve(objective.hessian(weights), gradient)
    assert np.abs(newton).max() < 2e-4 and gradient @ newton < 1e-10


def test_objective_is_the_chain_conditional_likelihood(shared_data: Path) -> None:
    objective, training = mixed_objective(shared_data, 120, l2=0.5)
    weights = np.random.default_rng(1).normal(size=int(objective.learned.sum()))
    factors = objective.factors(objective.full(weights))
    expected = chain.path_score(factors, training.labels) - chain.log_partition(factors) - 0.25 * weights @ weights
    assert -objective(weights)[0] * len(training.labels) == pytest.approx(expected, rel=1e-10)


def decode_accuracies(table: pl.DataFrame, n_classes: int, classes: list[str]) -> dict[str, float]:
    """Learn examples/temporal.mln (cll) and the paper's template (pll) on 'train'; frame accuracies on 'test'."""
    columns = artifacts.feature_columns(table)
    test = table.filter(pl.col("split") == "test")
    evidence, labels = test.select(columns).to_numpy().astype(bool), test["label"].to_numpy()
    starts = chain.chain_starts(test["episode"].to_numpy())
    mln = read_spec(TEMPORAL)
    formulas_for(mln, TEMPORAL, columns, classes)
    learned = stage.learn(table, n_classes, mln)
    assert learned.objective == "cll" and learned.l2 == cll.DEFAULT_L2
    factors = MLNFactors.from_weights(learned.weights, columns, n_classes).chain(evidence, starts)
    paper = read_spec(DEFAULT_SPEC)
    paper_weights = stage.learn(table, n_classes, paper).weights
    per_frame = MLNFactors.from_weights(paper_weights, columns, n_classes).unary(evidence)
    return {
        "viterbi": float((chain.viterbi(factors) == labels).mean()),
        "filter": float((chain.filtered(factors).argmax(axis=1) == labels).mean()),
        "smoothed": float((chain.smoothed(factors).argmax(axis=1) == labels).mean()),
        "unary argmax": float((factors.unary.argmax(axis=1) == labels).mean()),
        "paper mln argmax": float((per_frame.argmax(axis=1) == labels).mean()),
    }


def test_learned_transitions_decode_desk_better_than_per_frame(shared_data: Path) -> None:
    table = held_out(desk_predicates(shared_data)[0], by_episode=False)  # one training episode: its last 281 frames
    accuracy = decode_accuracies(table, 7, [f"S{k + 1}" for k in range(7)])
    per_frame = max(accuracy["unary argmax"], accuracy["paper mln argmax"])
    assert accuracy["viterbi"] > per_frame + 0.05, accuracy
    assert accuracy["filter"] > per_frame and accuracy["smoothed"] > per_frame, accuracy


@pytest.mark.mujoco
def test_learned_transitions_decode_fetch_better_than_per_frame(fetch_frames_workdir: Path) -> None:
    frames, meta = artifacts.read_table(fetch_frames_workdir / artifacts.FRAMES, "frames")
    table = binarize.binarize(frames, binarize.load_spec(binarize.default_spec_path("fetch")))
    table = held_out(table.with_columns(pl.lit("train").alias("split")), by_episode=True)  # the last episode held out
    accuracy = decode_accuracies(table, len(meta["classes"]), list(meta["classes"]))
    per_frame = max(accuracy["unary argmax"], accuracy["paper mln argmax"])
    assert accuracy["viterbi"] > per_frame + 0.05, accuracy
    assert accuracy["filter"] > per_frame, accuracy


def test_metric_sample_draws_whole_chains_evenly() -> None:
    starts = np.zeros(1000, dtype=bool)
    starts[::50] = True  # 20 chains of 50 frames
    assert cll.metric_sample(starts, most=1000) is None
    rows = cll.metric_sample(starts, most=300)  # every 4th chain: 5 of them
    chains = np.cumsum(starts) - 1
    assert sorted(set(chains[rows].tolist())) == [0, 4, 8, 12, 16]
    assert all(np.sum(chains[rows] == c) == 50 for c in (0, 4, 8, 12, 16))  # whole chains
    assert cll.metric_sample(np.eye(1, 1000, dtype=bool)[0], most=300) is None  # one long chain: all of it


@pytest.mark.mujoco
def test_a_sampled_metric_reaches_the_whole_datas_optimum(fetch_frames_workdir: Path) -> None:
    """With the exact Hessian measured on a third of the chains, BFGS still stops at the optimum of all frames: the
    Newton step there, by the Hessian of all frames, is as negligible as where the metric saw every chain."""
    frames, meta = artifacts.read_table(fetch_frames_workdir / artifacts.FRAMES, "frames")
    table = binarize.binarize(frames, binarize.load_spec(binarize.default_spec_path("fetch")))
    training = stage.training_data(table.with_columns(pl.lit("train").alias("split")), len(meta["classes"]))
    expanded, _, _ = expand_templates(read_spec(TEMPORAL).formulas, training.space)
    states = AtomSpace(training.space.words, tuple(class_constant(k) for k in range(len(meta["classes"]))))
    args = (expanded, training.evidence, training.labels, training.starts, states)
    third = len(training.labels) // 3
    assert len(cll.metric_sample(training.starts, third)) < len(training.labels) / 2
    whole, sampled = cll.learn(*args), cll.learn(*args, metric_frames=third)
    objective = cll.Objective(*args, cll.DEFAULT_L2)
    for weights in (whole, sampled):
        _, gradient = objective(weights[objective.learned])
        newton = np.linalg.solve(objective.hessian(weights[objective.learned]), gradient)
        assert np.abs(newton).max() < 2e-4 and gradient @ newton < 1e-10
    assert np.abs(whole - sampled)[objective.learned].max() < 1e-3
