"""predict: a model file over a user's recording, with or without labels; its metrics are eval's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog import artifacts
from mlnseq import export, predict
from mlnseq.timeline import metrics
from mlnseq.catalog.errors import BadInput
from mlnseq.recognition.reading import ReadOptions


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
    assert table.columns == ["episode", "frame", "time", "label", "class", *(artifacts.class_probability_column(name) for name in classes)]
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
    assert result.table.group_by("episode").len().sort("episode").rows() == [("a", 300), ("b", 200)]  # the files' names
    whole = predict.run(predict.PredictOptions(model=combined, source=folder / "a.csv", output=tmp_path / "a.parquet"))
    assert whole.table.drop("episode").equals(result.table.filter(pl.col("episode") == "a").drop("episode"))


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
                                                 reading=ReadOptions(decode="viterbi")))
    runs = {name: int((t["class"] != t["class"].shift(1)).sum()) for name, t in (("f", online.table), ("v", offline.table))}
    assert runs["v"] <= runs["f"]  # the most probable path switches no more often than the online belief
    assert offline.metrics["edit"] >= online.metrics["edit"] - 5
    with pytest.raises(BadInput, match="exported without decoding"):
        predict.run(predict.PredictOptions(model=combined, source=source, output=tmp_path / "x.parquet",
                                           reading=ReadOptions(decode="viterbi")))


# --- a frame that no allowed transition reaches ----------------------------------------------------------


def streamed(model: Path, frames: pl.DataFrame, episodes: list | None = None) -> list:
    """Recognizer.step over the frames, reset wherever ``episodes`` changes (the live loop)."""
    from mlnseq.recognition.recognizer import Recognizer

    recognizer = Recognizer.load(model)
    out, previous = [], None
    for index, row in enumerate(frames.select(recognizer.features).iter_rows(named=True)):
        if episodes is not None and episodes[index] != previous:
            recognizer.reset()
            previous = episodes[index]
        out.append(recognizer.step(row))
    return out


def assert_same_as_stream(table: pl.DataFrame, steps: list) -> None:
    assert table["class"].to_list() == [s.name for s in steps]
    probabilities = table.select(pl.col("^p_.*$")).to_numpy()
    assert np.abs(probabilities - np.array([s.probabilities for s in steps])).max() < 1e-6  # float32 column


def test_a_frame_that_breaks_a_hard_rule_restarts_the_chain_as_the_stream_does(own_data_glitch, tmp_path):
    csv, model, frame = own_data_glitch["csv"], own_data_glitch["model"], own_data_glitch["frame"]
    columns = dict(label_column="phase", episode_column="trial", time_column="t")
    result = predict.run(predict.PredictOptions(model=model, source=csv, output=tmp_path / "out.parquet",
                                                reading=ReadOptions(**columns)))
    assert result.restarts == [(11, frame)]
    frames = pl.read_csv(csv)
    steps = streamed(model, frames, frames["trial"].to_list())
    assert_same_as_stream(result.table, steps)
    assert [i for i, s in enumerate(steps) if s.restarted] == [frames["trial"].to_list().index(11) + frame]
    _, meta = artifacts.read_table(result.path, "predicted")
    assert meta["restarts"] == [["11", frame]]
    viterbi = predict.run(predict.PredictOptions(model=model, source=csv, output=tmp_path / "v.parquet",
                                                 reading=ReadOptions(**columns, decode="viterbi")))
    assert viterbi.restarts == [(11, frame)]


def test_merged_episodes_are_decoded_as_the_stream_decodes_them(own_data_glitch, tmp_path):
    """New recordings without the trial column are one episode: where the order's hard rules leave a frame no
    class, the chain restarts (as the live filter does) and predict names it."""
    model = own_data_glitch["model"]
    csv = tmp_path / "merged.csv"
    pl.read_csv(own_data_glitch["csv"]).drop("trial").with_columns(run=pl.lit(0), t=pl.int_range(pl.len())).write_csv(csv)
    result = predict.run(predict.PredictOptions(model=model, source=csv, output=tmp_path / "out.parquet",
                                                reading=ReadOptions(episode_column="run")))
    assert result.episodes == 1 and len(result.restarts) >= 1 and {e for e, _ in result.restarts} == {0}
    steps = streamed(model, pl.read_csv(csv))
    assert_same_as_stream(result.table, steps)
    assert [f for _, f in result.restarts] == [i for i, s in enumerate(steps) if s.restarted]

