"""report: tables, statements and figures from a small real run folder (DESK, one seed, 2 epochs)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import polars as pl
import pytest

from mlnseq.catalog import artifacts, methods
from mlnseq import conflate, report, train
from mlnseq import eval as evaluation
from mlnseq.catalog.errors import BadInput
from mlnseq.reporting import claims, loading, tables

from choice_rule import expected_choice  # tests/choice_rule.py


@pytest.fixture(scope="module")
def desk_run(tmp_path_factory, desk_mln_workdir, desk_folds_workdir) -> Path:
    """RUNS/desk/{segment,stream}/seed-0 laid out as `make reproduce` does, from the shared DESK artifacts, and
    RUNS/desk-temporal/stream/seed-0 from the cross-validated stream workdir (examples/temporal.mln, 3 folds)."""
    runs = tmp_path_factory.mktemp("runs")
    dataset = runs / "desk"
    dataset.mkdir()
    for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.FORMULAS, artifacts.WEIGHTS):
        shutil.copy(desk_mln_workdir / name, dataset / name)
    for mode in ("segment", "stream"):
        workdir = dataset / mode / "seed-0"
        workdir.mkdir(parents=True)
        for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS):
            (workdir / name).symlink_to(Path("../..") / name)
        for method in train.METHODS:
            # the segment mode's curves are measured every epoch, as `make reproduce` trains them (CURVES)
            train.run(workdir, train.TrainOptions(method=method, mode=mode, epochs=2, seed=0, folds=0,
                                                  measure="every-epoch" if mode == "segment" else None))
        conflate.run(workdir, conflate.ConflateOptions())
        evaluation.run(workdir, evaluation.EvalOptions())
    temporal = runs / "desk-temporal"
    workdir = temporal / "stream" / "seed-0"
    (workdir / artifacts.MODELS_DIR).mkdir(parents=True)
    for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.FORMULAS, artifacts.WEIGHTS, artifacts.FOLD_WEIGHTS):
        shutil.copy(desk_folds_workdir / name, temporal / name)
        if name != artifacts.FORMULAS:
            (workdir / name).symlink_to(Path("../..") / name)
    for method in train.METHODS:
        shutil.copy(artifacts.checkpoint_path(desk_folds_workdir, method), artifacts.checkpoint_path(workdir, method))
        shutil.copy(artifacts.out_of_fold_path(desk_folds_workdir, method), artifacts.out_of_fold_path(workdir, method))
    shutil.copy(desk_folds_workdir / artifacts.PREDICTIONS, workdir / artifacts.PREDICTIONS)
    evaluation.run(workdir, evaluation.EvalOptions())
    (runs / loading.TIMINGS).write_text(
        "2026-01-01T00:00:00\t3.5\tcollect\t--env desk\n2026-01-01T00:00:04\t2.0\ttrain\t--method lstm\n"
        "2026-01-01T00:00:09\t1.0\ttrain\t--method lstm\n"
    )
    return runs


@pytest.fixture(scope="module")
def loaded(desk_run) -> loading.Run:
    return loading.load_run(desk_run)


def test_load_run_reads_every_seed_workdir(loaded, desk_folds_workdir):
    assert set(loaded.metrics["mode"].unique()) == {"segment", "stream"}
    assert set(loaded.metrics["dataset"].unique()) == {"desk", "desk-temporal"}
    meta = artifacts.read_metadata(desk_folds_workdir / artifacts.PREDICTIONS)
    cv = loaded.cv.filter((pl.col("dataset") == "desk-temporal") & (pl.col("metric") == "edit"))
    assert dict(cv.select("method", "value").iter_rows()) == {
        m: f["edit"] for m, f in meta["cross_validation"]["figures"].items()}
    weights = loaded.network_weights.filter(pl.col("dataset") == "desk-temporal")
    assert dict(weights.select("method", "value").iter_rows()) == {
        m: c["weight"] for m, c in meta["network_weights"].items()}
    assert loaded.datasets["desk-temporal"]["formulas"] == "temporal.mln"
    assert loaded.datasets["desk-temporal"]["objective"] == "cll"
    assert set(loaded.logs["epoch"].unique()) == {1, 2}
    assert loaded.datasets["desk"]["n_train"] == 1405
    assert loaded.settings["train"]["epochs"] == [2]


def test_the_reports_choices_weigh_frames_by_each_folds_figures(loaded, desk_folds_workdir):
    from mlnseq.reporting import latency

    recorded = artifacts.read_metadata(desk_folds_workdir / artifacts.PREDICTIONS)["cross_validation"]
    scored = [s for s in latency.scored(loaded, "desk") if s.folder == "desk-temporal"]
    assert scored and all(list(s.candidate.fold_frames) == recorded["fold_frame_accuracy"][s.candidate.name]
                          for s in scored)
    online = latency.choose(scored, 0)  # the report's online choice: lag 0
    fitting = {s.candidate.name: s.candidate.figures for s in scored
               if not s.candidate.decoding.decoder.offline and not s.candidate.decoding.lag}
    assert online.candidate.name == expected_choice(fitting, recorded["fold_frame_accuracy"])


def test_table_iii_puts_the_paper_beside_the_measured_value(loaded):
    rows = tables.table_iii(loaded)
    assert [r[1] for r in rows] == [tables.METHOD_NAMES[m] for m in methods.METHODS]
    measured = loaded.metrics.filter((pl.col("mode") == "segment") & (pl.col("method") == "mln")
                                     & (pl.col("metric") == "segment_accuracy"))["value"][0]
    mln = rows[methods.METHODS.index("mln")]
    assert mln[2] == "49" and mln[3] == f"{100 * measured:.1f}"


def test_confusion_counts_every_test_segment(loaded):
    matrix = tables.confusion_matrix(loaded, "desk", "lstm")
    assert matrix.sum() == 725  # DESK's test segments


def test_claims_are_computed_from_the_numbers():
    metrics = pl.DataFrame({
        "dataset": ["fetch"] * 5, "mode": ["segment"] * 5, "seed": [0] * 5,
        "method": list(methods.METHODS), "metric": ["segment_accuracy"] * 5, "item": ["0.5"] * 5,
        "value": [0.70, 0.50, 0.65, 0.72, 0.71],  # lstm, mln, priorlayer, conflation, combined
    })
    run = loading.Run(metrics, pl.DataFrame(schema={"dataset": pl.String, "mode": pl.String, "seed": pl.Int64,
                                                   "method": pl.String, "epoch": pl.Int32, "split": pl.String,
                                                   "accuracy": pl.Float64}),
                     {}, {}, {}, loading.read_timings(Path("absent.tsv")))
    lines = claims.claims(run)
    assert any("PriorLayer improves on the LSTM" in line and "does not hold here, -5.0" in line for line in lines)
    assert any("Conflation improves on the LSTM" in line and "holds here, +2.0" in line for line in lines)
    assert any("best of the five: does not hold: LSTM + Conflation" in line for line in lines)


def test_efficiency_claim_names_where_the_gain_fades():
    points = pl.DataFrame({
        "method": ["lstm", "combined"] * 3, "train_share": [0.01, 0.01, 0.1, 0.1, 0.5, 0.5],
        "mean": [60.0, 70.0, 90.0, 92.0, 98.0, 98.2], "std": [1.0] * 6,
    })
    text = claims.efficiency_claim(points)
    assert "below 1 point from 50.0%" in text and "at 10.0%" in text


def test_wall_seconds_spans_first_start_to_last_end(loaded):
    assert tables.wall_seconds(loaded.timings) == pytest.approx(10.0)
    assert tables.timings_table(loaded.timings)[1][:2] == ["train", "1"]  # the latest run of a command only


def test_decoded_rows_come_from_the_temporal_folder(loaded):
    rows = tables.decoded_table(loaded)
    assert {(r[0], r[1]) for r in rows} == {("desk", "stream")}
    assert [r[2] for r in rows][:len(methods.METHODS)] == [tables.METHOD_NAMES[m] for m in methods.METHODS]
    viterbi = next(r for r in rows if r[2] == "LSTM + Conflation + Viterbi (offline)")
    frame = loaded.metrics.filter((pl.col("dataset") == "desk-temporal") & (pl.col("method") == "conflation+viterbi")
                                  & (pl.col("metric") == "frame_accuracy"))["value"][0]
    assert viterbi[4] == f"{100 * frame:.1f}"
    chosen = loaded.network_weights.filter(pl.col("method") == "conflation+viterbi")["value"][0]
    assert viterbi[7] == f"{chosen:.3g}"


def sequence_run(test: dict[str, float], cv: dict[str, float]) -> loading.Run:
    """A Run of two seeds whose DESK stream folders score each (folder, method) as given (test frame accuracy and
    segment accuracy alike, edit 95), and likewise cross-validated on the training split (edit 95)."""
    metrics, checked = [], []
    for (folder, method), value in test.items():
        for seed in (0, 1):
            for metric, scaled in (("segment_accuracy", value), ("frame_accuracy", value), ("edit", 95.0 * 100)):
                metrics.append((folder, "stream", seed, method, metric, "", scaled / 100))
            for metric, scaled in (("segment_accuracy", cv[(folder, method)]), ("frame_accuracy", cv[(folder, method)]),
                                   ("edit", 95.0), ("f1_50", 50.0)):
                checked.append((folder, "stream", seed, method, metric, scaled))
    schema = ["dataset", "mode", "seed", "method", "metric", "item", "value"]
    return loading.Run(pl.DataFrame(metrics, schema=schema, orient="row"), pl.DataFrame(), {}, {}, {},
                       loading.read_timings(Path("absent.tsv")),
                       cv=pl.DataFrame(checked, schema=loading.CV_SCHEMA, orient="row"))


def test_the_method_to_deploy_is_chosen_by_cross_validation_never_on_test():
    run = sequence_run(
        test={("desk-temporal", "conflation+viterbi"): 80.0, ("desk-temporal", "mln+viterbi"): 60.0,
              ("desk-conjunctive", "conflation+filter"): 76.0, ("desk", "lstm+filter"): 50.0},
        cv={("desk-temporal", "conflation+viterbi"): 70.0, ("desk-temporal", "mln+viterbi"): 90.0,
            ("desk-conjunctive", "conflation+filter"): 75.0, ("desk", "lstm+filter"): 76.0})
    choices = tables.deploy_choices(run, "desk")
    assert (choices["viterbi"]["folder"], choices["viterbi"]["method"]) == ("desk-temporal", "mln+viterbi")
    assert (choices["filter"]["folder"], choices["filter"]["method"]) == ("desk", "lstm+filter")
    assert choices["best_on_test"]["segment_accuracy"]["method"] == "conflation+viterbi"
    lines = claims.target_checks(run)
    offline = next(line for line in lines if line.startswith("desk, offline choice ("))
    assert "MLN + Viterbi (offline), learned transitions" in offline
    assert "edit 95.0 ± 0.0 (target ≥ 90: met)" in offline and "segment accuracy 60.0 ± 0.0 (target ≥ 70: **missed**)" in offline
    online = next(line for line in lines if line.startswith("desk, online choice ("))
    assert "segment accuracy 50.0 ± 0.0 (target ≥ 74: **missed**)" in online
    optimistic = next(line for line in lines if "**optimistic**" in line)
    assert "segment accuracy 80.0 ± 0.0 (LSTM + Conflation + Viterbi (offline), learned transitions)" in optimistic
    assert "deploy **LSTM + filter (online), no transitions** (`desk`)" in claims.deploy_sentence(run, "desk")
    assert claims.deploy_sentence(run, "fetch") is None and not any(line.startswith("fetch") for line in lines)
    rows = tables.deploy_table(run)
    chosen = next(r for r in rows if r[2].startswith("**chosen**") and r[1] == "online")
    assert chosen[3] == "no transitions (`desk`)" and chosen[4] == "76.0 ± 0.0" and chosen[8] == "50.0 ± 0.0"
    summary = tables.summary(run)["desk"]
    assert summary["online"]["method"] == "lstm+filter" and summary["online"]["cv"]["segment_accuracy"] == 76.0
    assert summary["offline"]["test"] == {"segment_accuracy": 60.0, "frame_accuracy": 60.0, "edit": 95.0,
                                          "f1_50": None}


def test_the_live_choice_keeps_the_budget_and_breaks_ties_by_the_cross_validated_log_likelihood():
    from dataclasses import replace

    from mlnseq.reporting import latency

    cv = {("desk-temporal", "conflation+smooth@25"): 80.0, ("desk-temporal", "mln+smooth@10"): 80.0,
          ("desk-temporal", "lstm+smooth@50"): 95.0, ("desk-temporal", "conflation+posterior"): 85.0,
          ("desk", "lstm"): 70.0, ("desk", "lstm+filter"): 60.0}
    run = sequence_run(test={key: value - 10.0 for key, value in cv.items()}, cv=cv)
    likelihoods = [("desk-temporal", "stream", seed, method, "log_likelihood", value)
                   for method, values in (("conflation+smooth@25", (-0.4, -0.6)), ("mln+smooth@10", (-0.8, -1.0)))
                   for seed, value in zip((0, 1), values)]
    run = replace(run, cv=pl.concat([run.cv, pl.DataFrame(likelihoods, schema=loading.CV_SCHEMA, orient="row")]))
    summary = latency.live_summary(run, "desk", {})
    live = summary["live"]
    assert (live["folder"], live["method"], live["lag_frames"]) == ("desk-temporal", "conflation+smooth@25", 25)
    assert live["cv"]["log_likelihood"] == pytest.approx(-0.5) and live["cv"]["segment_accuracy"] == 80.0
    assert live["test"]["segment_accuracy"] == 70.0
    assert (summary["online"]["method"], summary["online"]["decoder"]) == ("lstm", "none")
    assert summary["offline"]["method"] == "conflation+posterior"


def test_run_writes_the_report_and_its_figures(desk_run, tmp_path):
    result = report.run(report.ReportOptions(runs=desk_run, out=tmp_path))
    text = result.path.read_text()
    assert "**Not run:** fetch" in text
    for name in ("fig7_test_accuracy.png", "fig8_train_vs_test.png", "confusion_desk.png", "data_efficiency.png",
                 "timeline_desk.png"):
        assert f"({name})" in text
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"
    assert "desk: stream mode, seed 0, test episode 1 (the first wholly in the test split), frames 0–599" in text
    assert "- desk: deploy **" in text and "- desk, online choice (" in text
    assert "## Why: worked examples" in text and "### desk: a segment the MLN got" in text
    summary = json.loads((tmp_path / report.SUMMARY).read_text())
    assert {"online", "offline", "lstm"} <= set(summary["desk"]) <= {"online", "offline", "lstm", "live"}
    assert summary["desk"]["online"]["decoder"] == "filter" and "forbidden_transitions" in summary["desk"]["online"]
    assert set(summary["desk"]["online"]["cv"]) == {"segment_accuracy", "frame_accuracy", "edit", "f1_50"}
    assert result.n_seed_runs == 3


def test_the_worked_examples_explain_desk_segments_as_conflate_decided_them(desk_run):
    from mlnseq.reporting import worked_examples

    run = worked_examples.decided(desk_run / "desk-temporal" / "stream" / "seed-0")
    predictions = pl.read_parquet(desk_run / "desk-temporal" / "stream" / "seed-0" / artifacts.PREDICTIONS)
    assert (run.scores.path == predictions[artifacts.pred_column(worked_examples.METHOD)].to_numpy()).all()
    text = "\n".join(worked_examples.worked_examples(desk_run, ["desk"], {"desk-temporal": 0}))
    assert "### desk: a segment the MLN got wrong" in text and "the margin" in text and "line " in text
    blocks = text.split("```")[1::2]  # the explanations, as `mlnseq explain` prints them
    assert blocks and max(len(line) for block in blocks for line in block.splitlines()) <= 80


def test_a_folder_without_results_is_bad_input(tmp_path):
    with pytest.raises(BadInput, match="run `make reproduce` first"):
        report.run(report.ReportOptions(runs=tmp_path, out=tmp_path / "out"))
    with pytest.raises(BadInput, match="is not a folder"):
        report.run(report.ReportOptions(runs=tmp_path / "absent", out=tmp_path / "out"))


def test_a_tcn_folder_s_rows_name_its_network_tcn():
    """The stream table's D-tcn rows (networks trained with --cell tcn) say TCN, the paper folders' LSTM."""
    names = [(d, m) for d in ("desk", "desk-tcn") for m in methods.METHODS]
    metrics = pl.DataFrame({
        "dataset": [d for d, _ in names], "mode": ["stream"] * len(names), "seed": [0] * len(names),
        "method": [m for _, m in names], "metric": ["segment_accuracy"] * len(names), "item": ["0.5"] * len(names),
        "value": [0.5] * len(names),
    })
    run = loading.Run(metrics, pl.DataFrame(), {}, {}, {}, loading.read_timings(Path("absent.tsv")))
    rows = {(r[0], r[1]) for r in tables.stream_table(run)}
    assert {name for folder, name in rows if folder == "desk-tcn"} == {
        "TCN", "MLN", "TCN + PriorLayer", "TCN + Conflation", "PriorLayer + Conflation (combined)"}
    assert {name for folder, name in rows if folder == "desk"} == set(tables.METHOD_NAMES.values())
    assert tables.method_name("conflation+viterbi", "fetch-tcn") == "TCN + Conflation + Viterbi (offline)"
