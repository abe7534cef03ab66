"""The report's claims read their own figures (issue 55): each claim names the methods it compares and prints
their figures, not another method's. One test per claim of stages/reporting/claims.py, on a run whose methods all
score differently, so a figure printed for the wrong method is caught."""

from __future__ import annotations

import re
from pathlib import Path

import polars as pl
import pytest

from mlnseq.catalog import methods
from mlnseq.reporting import claims, loading

# segment accuracy per method (lstm, mln, priorlayer, conflation, combined): all different, on purpose
DESK = dict(zip(methods.METHODS, (0.357, 0.491, 0.612, 0.583, 0.640)))  # the LSTM weakest, combined best
FETCH = dict(zip(methods.METHODS, (0.700, 0.500, 0.650, 0.720, 0.710)))  # the MLN weakest, conflation best
LOG_SCHEMA = {"dataset": pl.String, "mode": pl.String, "seed": pl.Int64, "method": pl.String, "epoch": pl.Int32,
              "split": pl.String, "accuracy": pl.Float64}


def run_of(logs: pl.DataFrame | None = None) -> loading.Run:
    rows = [(dataset, "segment", 0, method, "segment_accuracy", "0.5", value)
            for dataset, values in (("desk", DESK), ("fetch", FETCH)) for method, value in values.items()]
    metrics = pl.DataFrame(rows, schema=["dataset", "mode", "seed", "method", "metric", "item", "value"], orient="row")
    return loading.Run(metrics, logs if logs is not None else pl.DataFrame(schema=LOG_SCHEMA), {}, {}, {},
                       loading.read_timings(Path("absent.tsv")))


def line(lines: list[str], dataset: str, claim: str) -> str:
    found = [text for text in lines if text.startswith(f"{dataset}: ") and claim in text]
    assert len(found) == 1, (claim, lines)
    return found[0]


def figures(text: str) -> list[float]:
    return [float(x) for x in re.findall(r"[-+]?\d+\.\d", text)]


@pytest.mark.parametrize("better, claim", [("priorlayer", "PriorLayer improves on the LSTM"),
                                           ("conflation", "Conflation improves on the LSTM"),
                                           ("combined", "the combined model improves on the LSTM")])
@pytest.mark.parametrize("dataset, values", [("desk", DESK), ("fetch", FETCH)])
def test_an_improvement_claim_prints_its_own_difference(better, claim, dataset, values):
    text = line(claims.claims(run_of()), dataset, claim)
    diff = 100 * (values[better] - values["lstm"])
    assert figures(text.split("here,")[1])[0] == pytest.approx(round(diff, 1))
    assert ("does not hold" in text) == (diff <= 0)


@pytest.mark.parametrize("dataset, values", [("desk", DESK), ("fetch", FETCH)])
def test_the_best_claim_prints_the_best_and_the_combined_figures(dataset, values):
    text = line(claims.claims(run_of()), dataset, "the combined model is the best of the five")
    best = max(values, key=values.get)
    assert figures(text) == pytest.approx([round(100 * values[best], 1), round(100 * values["combined"], 1)])
    assert ("does not hold" in text) == (best != "combined")


@pytest.mark.parametrize("dataset, values", [("desk", DESK), ("fetch", FETCH)])
def test_the_weakest_claim_prints_the_weakest_method_s_own_figure(dataset, values):
    text = line(claims.claims(run_of()), dataset, "the MLN alone is the weakest")
    weakest = min(values, key=values.get)
    shown = figures(text)
    assert shown[0] == pytest.approx(round(100 * values[weakest], 1))  # the weakest, named, with its own figure
    assert round(100 * values["mln"], 1) in shown
    if weakest != "mln":
        assert "LSTM is weakest here (35.7 vs MLN 49.1)" in text


def test_the_regularisation_claim_prints_each_network_s_own_gap():
    accuracy = {("lstm", "train"): 0.95, ("lstm", "test"): 0.60, ("priorlayer", "train"): 0.90,
                ("priorlayer", "test"): 0.70}
    logs = pl.DataFrame([("desk", "segment", 0, m, 5, split, a) for (m, split), a in accuracy.items()],
                        schema=LOG_SCHEMA, orient="row")
    text = line(claims.regularisation_claims(run_of(logs)), "desk", "PriorLayer narrows the train - test gap")
    assert "holds here" in text and "LSTM 35.0, PriorLayer 20.0 points" in text
