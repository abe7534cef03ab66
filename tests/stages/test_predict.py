"""predict: a model file over a user's recording, with or without labels; its metrics are eval's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from stages import artifacts, export, metrics, predict
from stages.errors import BadInput


@pytest.fixture(scope="module")
def combined(tmp_path_factory, desk_stream_workdir) -> Path:
    return export.run(desk_stream_workdir, export.ExportOptions(
        method="combined", output=tmp_path_factory.mktemp("model") / "combined.mlnseq")).path


def test_a_labelled_recording_is_recognised_and_scored_as_eval_scores_it(combined, desk_test_recording,
                                                                         desk_stream_workdir, tmp_path):
    result = predict.run(predict.PredictOptions(model=combined, source=desk_test_recording,
                                                output=tmp_path / "out.parquet"))
    table, meta = artifacts.read_table(result.path, "predicted")
    classes = meta["classes"]
    assert table.columns == ["episode", "frame", "label", "class", *(artifacts.class_probability_column(name) for name in classes)]
    assert table.height == 20_924 and set(table["class"]) <= set(classes)
    conflated = pl.read_parquet(desk_stream_workdir / artifacts.PREDICTIONS).filter(pl.col("split") == "test")
    expected = conflated[artifacts.pred_column("combined")].to_numpy()
    assert [classes[k] for k in expected] == table["class"].to_list()
    labels = conflated["label"].to_numpy().astype(np.int64)
    scores = metrics.score_method(expected, labels, np.zeros_like(labels), 7, 0.5, segmental=True)
    for name in ("segment_accuracy", "frame_accuracy", "edit", "f1@50"):
        assert result.metrics[name] == pytest.approx(scores[name]) and meta["metrics"][name] == pytest.approx(scores[name])


def test_an_unlabelled_folder_of_recordings_is_one_episode_per_file(combined, desk_test_recording, tmp_path):
    folder = tmp_path / "recordings"
    folder.mkdir()
    frames = pl.read_csv(desk_test_recording).drop("label")
    frames.head(300).write_csv(folder / "a.csv")
    frames.slice(300, 200).write_parquet(folder / "b.parquet")
    result = predict.run(predict.PredictOptions(model=combined, source=folder, output=tmp_path / "out.parquet"))
    assert result.metrics is None and "label" not in result.table.columns
    assert result.table.group_by("episode").len().sort("episode")["len"].to_list() == [300, 200]
    whole = predict.run(predict.PredictOptions(model=combined, source=folder / "a.csv", output=tmp_path / "a.parquet"))
    assert whole.table.drop("episode").equals(result.table.filter(pl.col("episode") == 0).drop("episode"))


def test_a_recording_without_the_model_features_names_every_missing_column(combined, desk_test_recording, tmp_path):
    source = tmp_path / "partial.csv"
    pl.read_csv(desk_test_recording).drop("left_gripper", "right_gripper").write_csv(source)
    with pytest.raises(BadInput, match="partial.csv: no column 'left_gripper', 'right_gripper'"):
        predict.run(predict.PredictOptions(model=combined, source=source, output=tmp_path / "out.parquet"))
    assert not (tmp_path / "out.parquet").exists()


def test_viterbi_decodes_a_filter_model_offline_and_refuses_an_undecoded_one(desk_stream_workdir, desk_test_recording,
                                                                           combined, tmp_path):
    source = tmp_path / "head.csv"
    pl.read_csv(desk_test_recording).head(3000).write_csv(source)
    filtering = export.run(desk_stream_workdir, export.ExportOptions(method="mln", decode="filter",
                                                                     output=tmp_path / "mln+filter.mlnseq")).path
    online = predict.run(predict.PredictOptions(model=filtering, source=source, output=tmp_path / "f.parquet"))
    offline = predict.run(predict.PredictOptions(model=filtering, source=source, output=tmp_path / "v.parquet",
                                                 decode="viterbi"))
    runs = {name: int((t["class"] != t["class"].shift(1)).sum()) for name, t in (("f", online.table), ("v", offline.table))}
    assert runs["v"] <= runs["f"]  # the most probable path switches no more often than the online belief
    assert offline.metrics["edit"] >= online.metrics["edit"] - 5
    with pytest.raises(BadInput, match="exported without decoding"):
        predict.run(predict.PredictOptions(model=combined, source=source, output=tmp_path / "x.parquet", decode="viterbi"))
