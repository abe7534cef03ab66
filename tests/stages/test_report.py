"""report: tables, statements and figures from a small real run folder (DESK, one seed, 2 epochs)."""

from __future__ import annotations

import shutil
from pathlib import Path

import polars as pl
import pytest

from stages import artifacts, conflate, recognizer, report, train
from stages import eval as evaluation
from stages.errors import BadInput
from stages.report import claims, loading, tables


@pytest.fixture(scope="module")
def desk_run(tmp_path_factory, desk_mln_workdir) -> Path:
    """RUNS/desk/{segment,stream}/seed-0 laid out as `make reproduce` does, from the shared DESK artifacts."""
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
            train.run(workdir, train.TrainOptions(method=method, mode=mode, epochs=2, seed=0))
        conflate.run(workdir, conflate.ConflateOptions())
        evaluation.run(workdir, evaluation.EvalOptions())
    (runs / loading.TIMINGS).write_text(
        "2026-01-01T00:00:00\t3.5\tcollect\t--env desk\n2026-01-01T00:00:04\t2.0\ttrain\t--method lstm\n"
        "2026-01-01T00:00:09\t1.0\ttrain\t--method lstm\n"
    )
    return runs


@pytest.fixture(scope="module")
def loaded(desk_run) -> loading.Run:
    return loading.load_run(desk_run)


def test_load_run_reads_every_seed_workdir(loaded):
    assert set(loaded.metrics["mode"].unique()) == {"segment", "stream"}
    assert set(loaded.metrics["dataset"].unique()) == {"desk"}
    assert set(loaded.logs["epoch"].unique()) == {1, 2}
    assert loaded.datasets["desk"]["n_train"] == 1405
    assert loaded.settings["train"]["epochs"] == [2]


def test_table_iii_puts_the_paper_beside_the_measured_value(loaded):
    rows = tables.table_iii(loaded)
    assert [r[1] for r in rows] == [tables.METHOD_NAMES[m] for m in recognizer.METHODS]
    measured = loaded.metrics.filter((pl.col("mode") == "segment") & (pl.col("method") == "mln")
                                     & (pl.col("metric") == "segment_accuracy"))["value"][0]
    mln = rows[recognizer.METHODS.index("mln")]
    assert mln[2] == "49" and mln[3] == f"{100 * measured:.1f}"


def test_confusion_counts_every_test_segment(loaded):
    matrix = tables.confusion_matrix(loaded, "desk", "lstm")
    assert matrix.sum() == 725  # DESK's test segments


def test_claims_are_computed_from_the_numbers():
    metrics = pl.DataFrame({
        "dataset": ["fetch"] * 5, "mode": ["segment"] * 5, "seed": [0] * 5,
        "method": list(recognizer.METHODS), "metric": ["segment_accuracy"] * 5, "item": ["0.5"] * 5,
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


def test_run_writes_the_report_and_its_figures(desk_run, tmp_path):
    result = report.run(report.ReportOptions(runs=desk_run, out=tmp_path))
    text = result.path.read_text()
    assert "**Not run:** fetch" in text
    for name in ("fig7_test_accuracy.png", "fig8_train_vs_test.png", "confusion_desk.png", "data_efficiency.png"):
        assert f"({name})" in text
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"
    assert result.n_seed_runs == 2


def test_a_folder_without_results_is_bad_input(tmp_path):
    with pytest.raises(BadInput, match="run `make reproduce` first"):
        report.run(report.ReportOptions(runs=tmp_path, out=tmp_path / "out"))
    with pytest.raises(BadInput, match="is not a folder"):
        report.run(report.ReportOptions(runs=tmp_path / "absent", out=tmp_path / "out"))
