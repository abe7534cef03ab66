"""The MLN's chain factors from weights.parquet: the paper's scores per frame, transitions, hard rules."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog import artifacts
from mlnseq import learn_weights as stage
from mlnseq.catalog.errors import BadInput
from mlnseq.formulas import DEFAULT_SPEC, formulas_for, read_spec
from mlnseq.mln import chain
from mlnseq.mln.classifier import class_scores
from mlnseq.mln.factors import MLNFactors
from mlnseq.mln.published_codes import desk_predicates, fetch_predicates
from mlnseq.mln.syntax import parse_mln

TEMPORAL = Path(__file__).resolve().parents[3] / "examples" / "temporal.mln"


@pytest.fixture(scope="module")
def desk(shared_data: Path) -> pl.DataFrame:
    return desk_predicates(shared_data)[0]


@pytest.fixture(scope="module")
def desk_temporal(desk: pl.DataFrame) -> pl.DataFrame:
    mln = read_spec(TEMPORAL)
    formulas_for(mln, TEMPORAL, artifacts.feature_columns(desk), [f"S{k + 1}" for k in range(7)])
    return stage.learn(desk, 7, mln).weights


def test_unary_is_the_paper_class_score(desk: pl.DataFrame, desk_temporal: pl.DataFrame) -> None:
    columns = artifacts.feature_columns(desk)
    test = desk.filter(pl.col("split") == "test")
    evidence = test.select(columns).to_numpy()
    for weights in (stage.learn(desk, 7, read_spec(DEFAULT_SPEC)).weights, desk_temporal):
        factors = MLNFactors.from_weights(weights, columns, 7)
        assert np.abs(factors.unary(evidence) - class_scores(test, weights, 7)).max() < 1e-12
    assert MLNFactors.from_weights(desk_temporal, columns, 7).temporal


def test_one_frame_at_a_time_gives_the_batch_numbers(desk: pl.DataFrame, desk_temporal: pl.DataFrame) -> None:
    columns = artifacts.feature_columns(desk)
    evidence = desk.select(columns).to_numpy()[:300]
    batch = MLNFactors.from_weights(desk_temporal, columns, 7)
    live = MLNFactors.from_weights(desk_temporal, columns, 7)
    starts = chain.chain_starts(desk["episode"].to_numpy()[:300])
    factors = batch.chain(evidence, starts)
    online = chain.Filter(7)
    for t, row in enumerate(evidence):
        unary = live.unary(row[None])[0]
        pairwise = None if starts[t] else live.pairwise(evidence[t - 1][None], row[None])[0]
        assert np.array_equal(unary, factors.unary[t])
        if pairwise is not None:
            assert np.array_equal(pairwise, factors.pairwise[factors.link[t]])
        step = online.step(unary, pairwise)
    assert np.abs(step - chain.filtered(factors)[-1]).max() < 1e-9
    assert len(factors.pairwise) == 1  # transitions read no evidence: one matrix for every step


def test_chain_layout_and_options(desk: pl.DataFrame, desk_temporal: pl.DataFrame) -> None:
    columns = artifacts.feature_columns(desk)
    evidence = desk.select(columns).to_numpy()[:50]
    starts = np.zeros(50, dtype=bool)
    starts[[0, 20]] = True
    factors = MLNFactors.from_weights(desk_temporal, columns, 7).chain(evidence, starts, per_frame=False)
    assert (factors.link[[0, 20]] == -1).all() and (factors.link[~starts] == 0).all()
    assert not factors.unary.any()
    weight = dict(zip(desk_temporal["formula"], desk_temporal["weight"]))
    for before, after in ((0, 1), (3, 4), (6, 2)):  # an implication is broken by every other class after `before`
        transition = weight[f'Topic("C{before}",p) ^ Next(p,q) => Topic("C{after}",q)']
        stay = weight[f'Topic("C{before}",p) ^ Next(p,q) => Topic("C{before}",q)']
        assert factors.pairwise[0, before, after] - factors.pairwise[0, before, before] == pytest.approx(transition - stay)
    paper = MLNFactors.from_weights(stage.learn(desk, 7, read_spec(DEFAULT_SPEC)).weights, columns, 7)
    assert not paper.temporal
    uniform = paper.chain(evidence, starts)
    assert not uniform.pairwise.any() and (uniform.link[~starts] >= 0).all()


def test_hard_rules_forbid(shared_data: Path) -> None:
    table = fetch_predicates(shared_data)[0]
    columns = artifacts.feature_columns(table)
    mln = parse_mln("Has(word, page)\nTopic(class, page)\nNext(page, page)\n"
                    "0.0 Has(+w, p) => Topic(+c, p)\n"
                    'Topic("C0", p) ^ Next(p, q) => Topic("C0", q) v Topic("C1", q).\n'
                    'Has("gripper_closing", p) => !Topic("C3", p).\n')
    weights = stage.learn(table, 4, mln).weights
    assert weights.filter(pl.col("hard"))["temporal"].to_list() == [True, False]
    factors = MLNFactors.from_weights(weights, columns, 4)
    transitions = factors.pairwise(np.zeros((1, len(columns)), bool), np.zeros((1, len(columns)), bool))[0]
    assert np.isneginf(transitions[0, 2:]).all() and np.isfinite(transitions[0, :2]).all()
    assert np.isfinite(transitions[1:]).all()
    closing = np.array([[c == "gripper_closing" for c in columns]])
    assert np.isneginf(factors.unary(closing)[0, 3]) and np.isfinite(factors.unary(closing)[0, :3]).all()
    path = chain.viterbi(factors.chain(table.select(columns).to_numpy(), chain.chain_starts(table["episode"].to_numpy())))
    assert not ((path[:-1] == 0) & (path[1:] >= 2)).any()


def test_a_formula_over_a_missing_column_is_refused(desk: pl.DataFrame, desk_temporal: pl.DataFrame) -> None:
    columns = [c for c in artifacts.feature_columns(desk) if c != "left_gripper_closed"]
    with pytest.raises(BadInput, match="left_gripper_closed, which predicates.parquet lacks"):
        MLNFactors.from_weights(desk_temporal, columns, 7)


def test_transitions_that_read_evidence(shared_data: Path) -> None:
    table = fetch_predicates(shared_data)[0]
    columns = artifacts.feature_columns(table)
    mln = parse_mln("Has(word, page)\nTopic(class, page)\nNext(page, page)\n"
                    "0.0 Topic(+c1, p) ^ Next(p, q) => Topic(+c2, q)\n"
                    '0.0 Topic(+c1, p) ^ Next(p, q) ^ Has("gripper_closing", q) => Topic(+c2, q)\n')
    weights = stage.learn(table, 4, mln).weights
    weight = dict(zip(weights["formula"], weights["weight"]))
    evidence = table.select(columns).to_numpy()
    factors = MLNFactors.from_weights(weights, columns, 4).chain(evidence, chain.chain_starts(table["episode"].to_numpy()))
    assert len(factors.pairwise) == 2  # the later frame closes its gripper or not: two transition matrices
    closing = evidence[:, columns.index("gripper_closing")]
    with_closing = factors.pairwise[factors.link[np.flatnonzero(closing & (factors.link >= 0))[0]]]
    without = factors.pairwise[factors.link[np.flatnonzero(~closing & (factors.link >= 0))[0]]]
    extra = weight['Topic("C0",p) ^ Next(p,q) ^ Has("gripper_closing",q) => Topic("C1",q)'] \
        - weight['Topic("C0",p) ^ Next(p,q) ^ Has("gripper_closing",q) => Topic("C0",q)']
    assert (with_closing - without)[0, 1] - (with_closing - without)[0, 0] == pytest.approx(extra)
