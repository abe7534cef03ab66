"""eval: its options, its core on tiny predictions with known scores (the metrics themselves: test_metrics.py), and
its run on a DESK workdir."""

import shutil

import pytest

from mlnseq import eval as stage
from mlnseq.catalog.errors import BadInput


@pytest.mark.parametrize("options", [stage.EvalOptions(fraction=0.0), stage.EvalOptions(fraction=1.2),
                                     stage.EvalOptions(method="hmm")])
def test_bad_options_are_refused(options):
    with pytest.raises(BadInput):
        options.validate()


def tiny_predictions():
    """Two test episodes (labels 0 0 0 0 1 1 | 1 1 1 1: three segments) and one training row, with lstm (segment
    mode) and mln (frame mode) predictions whose scores are worked out by hand below."""
    import polars as pl

    labels = [0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1]
    table = pl.DataFrame({
        "episode": [9, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1], "frame": [0, 0, 1, 2, 3, 4, 5, 0, 1, 2, 3], "label": labels,
        "split": ["train"] + ["test"] * 10,
        "lstm_pred": [1, 1, 0, 0, 0, 1, 0, 1, 1, 0, 0],  # the training row is wrong: it must not count
        "mln_pred": [1] + [0] * 10,
    })
    meta = {"methods": ["lstm", "mln"], "classes": ["c0", "c1"], "modes": {"lstm": "segment", "mln": "frame"}}
    return table, meta


def test_evaluate_scores_each_method_on_the_test_frames_only():
    table, meta = tiny_predictions()
    results = stage.evaluate(table, meta, stage.EvalOptions())
    # segments are recognised at frame max(int(len / 2) - 1, 0): frame 1 of a 4-frame segment, 0 of a 2-frame one
    lstm, mln = results["lstm"], results["mln"]
    assert lstm["segment_accuracy"] == 1.0 and lstm["frame_accuracy"] == 0.6
    assert mln["segment_accuracy"] == 1 / 3 and mln["frame_accuracy"] == 0.4
    assert mln["confusion"] == [[1, 0], [2, 0]] and mln["per_class"] == {0: 1.0, 1: 0.0}
    assert "edit" not in lstm  # a segment-mode network saw the boundaries
    assert mln["edit"] == 25.0  # episode 0: runs 0 | 0 1, one edit of two (50); episode 1: 0 | 1 (0)


def test_the_metrics_table_holds_every_score_in_long_form():
    table, meta = tiny_predictions()
    results = stage.evaluate(table, meta, stage.EvalOptions(fraction=0.5))
    metrics = stage.metrics_table(results, meta["classes"], 0.5)
    rows = {(m, metric, item): value for m, metric, item, value in metrics.iter_rows()}
    assert rows[("lstm", "segment_accuracy", "0.5")] == 1.0
    assert rows[("mln", "class_accuracy", "c1")] == 0.0
    assert rows[("mln", "confusion", "c1 -> c0")] == 2.0 and rows[("mln", "confusion", "c0 -> c1")] == 0.0
    assert rows[("mln", "edit", "")] == 25.0 and ("lstm", "edit", "") not in rows
    assert dict(metrics.schema) == stage.artifacts.METRICS_SCHEMA


def test_a_method_the_predictions_lack_is_refused_with_its_remedy():
    table, meta = tiny_predictions()
    with pytest.raises(BadInput, match=r"no 'combined\+filter' predictions .*train --method priorlayer` then "
                                       r"`mlnseq conflate --decode filter`"):
        stage.evaluate(table, meta, stage.EvalOptions(method="combined+filter"))


def test_methods_predicting_alike_get_the_same_scores_each_as_its_mode_asks():
    import polars as pl

    table, meta = tiny_predictions()
    table = table.with_columns(pl.col("lstm_pred").alias("mln_pred"), pl.col("lstm_pred").alias("conflation_pred"),
                               pl.col("lstm_pred").alias("lstm+filter_pred"))
    meta = {**meta, "methods": ["lstm", "mln", "conflation", "lstm+filter"],
            "modes": {"lstm": "segment", "mln": "frame", "conflation": "segment", "lstm+filter": "segment"}}
    results = stage.evaluate(table, meta, stage.EvalOptions())
    assert results["conflation"] == results["lstm+filter"] == results["lstm"]
    assert "edit" not in results["lstm"] and results["mln"]["edit"] == 50.0  # 1 0 1 0 | 1 0 vs 0 1 | 1
    assert {k: v for k, v in results["mln"].items() if not k.startswith(("edit", "f1@"))} == results["lstm"]


def test_run_reads_the_classes_it_scores_and_refuses_a_method_the_predictions_lack(desk_full_workdir, tmp_path):
    for path in desk_full_workdir.iterdir():  # a copy: eval writes metrics.parquet beside the predictions
        if path.is_file():
            shutil.copy(path, tmp_path / path.name)
    every = stage.run(tmp_path, stage.EvalOptions()).results
    one = stage.run(tmp_path, stage.EvalOptions(method="conflation")).results
    assert list(one) == ["conflation"] and one["conflation"] == every["conflation"]
    with pytest.raises(BadInput, match=r"no 'conflation\+filter' predictions .*conflate --decode filter`"):
        stage.run(tmp_path, stage.EvalOptions(method="conflation+filter"))
