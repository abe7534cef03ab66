"""predict reads new recordings as the model's own were read: the model file remembers the env and the
episode, time and label columns; the user's episode ids are kept; outputs are not overwritten unasked."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts
from mlnseq import collect, export, predict, train
from mlnseq.sources.desk import CLASSES as DESK_CLASSES
from mlnseq.catalog.errors import BadInput
from mlnseq.sources.recording import TableColumns
from mlnseq.recognition.reading import ReadOptions

TRIAL = 1500  # frames per trial


def as_trials(frames: pl.DataFrame, ids: list) -> pl.DataFrame:
    """DESK frames as a lab's log: trial ids, time in seconds at 20 Hz, phase names, the motion channels."""
    frames = frames.head(TRIAL * len(ids))
    return pl.DataFrame({
        "trial": [ids[i // TRIAL] for i in range(frames.height)],
        "t": [(i % TRIAL) * 0.05 for i in range(frames.height)],
        "phase": [DESK_CLASSES[k] for k in frames["label"]],
    }).hstack(frames.select("arm_distance", "left_gripper", "right_gripper"))


@pytest.fixture(scope="module")
def recordings(desk_test_recording, tmp_path_factory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("lab")
    frames = pl.read_csv(desk_test_recording)
    as_trials(frames, [f"T{k}" for k in range(6)]).write_csv(folder / "trials.csv")
    as_trials(frames.slice(6 * TRIAL), [101, 102]).write_csv(folder / "new_trials.csv")
    return folder / "trials.csv", folder / "new_trials.csv"


@pytest.fixture(scope="module")
def model(recordings, tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("lab-work")
    collect.run(workdir, collect.CollectOptions(env="table", source=recordings[0], columns=TableColumns(
        label="phase", episode="trial", time="t")))
    train.run(workdir, train.TrainOptions(method="lstm", mode="stream", epochs=1))
    return export.run(workdir, export.ExportOptions(method="lstm")).path


def test_the_model_file_records_how_its_recordings_were_read(model):
    with zipfile.ZipFile(model) as archive:
        manifest = json.loads(archive.read("manifest.json"))
    assert manifest["reading"] == {"env": "table", "label_column": "phase", "episode_column": "trial",
                                   "time_column": "t", "labels_unit": "frames"}
    assert manifest["classes"] == list(DESK_CLASSES)


def test_predict_reads_as_the_model_did_and_keeps_the_trial_ids(model, recordings, tmp_path):
    out = tmp_path / "new.parquet"
    result = predict.run(predict.PredictOptions(model=model, source=recordings[1], output=out))
    assert result.episodes == 2 and result.metrics is not None  # two trials, scored with their phase labels
    table, meta = artifacts.read_table(out, "predicted")
    assert table.group_by("episode", maintain_order=True).len().rows() == [(101, TRIAL), (102, TRIAL)]
    assert meta["episodes"] == [101, 102] and meta["reading"]["episode_column"] == "trial"
    with pytest.raises(BadInput, match="new.parquet exists; pass --force"):
        predict.run(predict.PredictOptions(model=model, source=recordings[1], output=out))
    again = predict.run(predict.PredictOptions(model=model, source=recordings[1], output=out, force=True))
    assert again.table.equals(result.table)
    renamed = tmp_path / "renamed.csv"
    pl.read_csv(recordings[1]).rename({"trial": "session"}).write_csv(renamed)
    with pytest.raises(BadInput, match="renamed.csv: no column 'trial'"):
        predict.run(predict.PredictOptions(model=model, source=renamed, output=tmp_path / "r.parquet"))
    flagged = predict.run(predict.PredictOptions(model=model, source=renamed, output=tmp_path / "r.parquet",
                                                 reading=ReadOptions(episode_column="session")))  # a flag overrides the model's reading
    assert flagged.table.equals(result.table)


def test_a_named_label_column_must_be_there_and_bad_values_name_row_and_column(model, recordings, tmp_path):
    unlabelled = tmp_path / "unlabelled.csv"
    pl.read_csv(recordings[1]).drop("phase").write_csv(unlabelled)
    plain = predict.run(predict.PredictOptions(model=model, source=unlabelled, output=tmp_path / "u.parquet"))
    assert plain.metrics is None and plain.episodes == 2  # the model's label column, absent: unlabelled
    with pytest.raises(BadInput, match="unlabelled.csv: no column 'phase'"):
        predict.run(predict.PredictOptions(model=model, source=unlabelled, output=tmp_path / "x.parquet",
                                           reading=ReadOptions(label_column="phase")))
    typo = tmp_path / "typo.csv"
    text = recordings[1].read_text().splitlines()
    cells = text[9].split(",")
    cells[4] = "0..3"  # left_gripper of line 10
    typo.write_text("\n".join([*text[:9], ",".join(cells), *text[10:]]) + "\n")
    with pytest.raises(BadInput, match=r"typo.csv:10: column 'left_gripper' is not numeric: it holds '0..3'"):
        predict.run(predict.PredictOptions(model=model, source=typo, output=tmp_path / "x.parquet"))
    assert not (tmp_path / "x.parquet").exists()


def test_predict_through_the_cli_refuses_to_overwrite(model, recordings, tmp_path):
    out = tmp_path / "p.parquet"
    runner = CliRunner()
    done = runner.invoke(app, ["predict", str(model), "--source", str(recordings[1]), "-o", str(out)])
    assert done.exit_code == 0, done.output
    assert "3,000 frames, 2 episodes" in " ".join(done.output.split())
    again = runner.invoke(app, ["predict", str(model), "--source", str(recordings[1]), "-o", str(out)])
    assert again.exit_code == 2 and "exists; pass --force" in again.stderr
    assert again.stderr.strip().count("\n") == 0


@pytest.mark.parametrize("unit", ["frames", "seconds"])
def test_predicted_intervals_read_back_as_labels_give_the_predicted_classes(model, recordings, tmp_path, unit):
    from mlnseq import sources
    from mlnseq.sources import SourceOptions
    from mlnseq.sources.table import collect_frames

    segments = tmp_path / f"segments-{unit}.csv"
    result = predict.run(predict.PredictOptions(model=model, source=recordings[1], output=tmp_path / "p.parquet",
                                                intervals=segments,
                                                reading=ReadOptions(overrides={"labels_unit": unit})))
    assert result.written == (segments,)
    written = pl.read_csv(segments)
    assert written.columns == ["episode", "start", "end", "label"] and set(written["episode"]) == {101, 102}
    unlabelled = tmp_path / "unlabelled.csv"
    pl.read_csv(recordings[1]).drop("phase").write_csv(unlabelled)
    back, meta = collect_frames(sources.read("table", unlabelled, TableColumns(episode="trial", time="t"),
                                             SourceOptions(labels=segments, labels_unit=unit)))
    assert back.height == result.table.height  # every frame in exactly one segment
    assert [meta["classes"][k] for k in back["label"]] == result.table["class"].to_list()


def test_predict_writes_a_rerun_recording_of_signals_classes_and_probabilities(model, recordings, tmp_path):
    rr = pytest.importorskip("rerun", reason="the [recordings] extra is not installed")
    path = tmp_path / "view.rrd"
    result = predict.run(predict.PredictOptions(model=model, source=recordings[1], output=tmp_path / "p.parquet",
                                                rerun=path))
    assert result.written == (path,)
    rows: dict[str, int] = {}
    timelines = set()
    for chunk in rr.chunk.RrdReader(path).stream():
        if chunk.entity_path.startswith("/episode/"):
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
            timelines |= set(chunk.timeline_names)
    for episode in ("101", "102"):
        expected = {f"/episode/{episode}/{e}" for e in (
            "features/arm_distance", "features/left_gripper", "features/right_gripper", "class/predicted", "class/true",
            *(f"probability/{rr.escape_entity_path_part(c)}" for c in DESK_CLASSES))}
        assert expected <= set(rows) and all(rows[e] == TRIAL for e in expected)
    assert {"time", "frame"} <= timelines
    with pytest.raises(BadInput, match="view.rrd exists; pass --force"):
        predict.run(predict.PredictOptions(model=model, source=recordings[1], output=tmp_path / "q.parquet", rerun=path))


def test_a_folder_partly_labelled_is_read_with_labels_where_a_recording_has_them(model, recordings, tmp_path):
    """Every command that reads with a model takes the folder fit took: one file with its phase column, one without
    (and then a labels file naming one of its trials): labels where a recording has them, never a refusal."""
    from mlnseq import explain

    folder = tmp_path / "mixed"
    folder.mkdir()
    new = pl.read_csv(recordings[1])
    new.write_csv(folder / "a.csv")
    new.drop("phase").with_columns(trial=pl.col("trial") + 100).write_csv(folder / "b.csv")
    result = predict.run(predict.PredictOptions(model=model, source=folder, output=tmp_path / "p.parquet"))
    assert result.episodes == 4 and (result.metrics["recordings"], result.metrics["of"]) == (2, 4)
    table = result.table
    assert table.filter(pl.col("episode").str.starts_with("b/"))["label"].null_count() == 2 * TRIAL
    assert table.filter(pl.col("episode").str.starts_with("a/"))["label"].to_list() == new["phase"].to_list()
    alone = predict.run(predict.PredictOptions(model=model, source=recordings[1], output=tmp_path / "a.parquet"))
    assert result.metrics["frame_accuracy"] == alone.metrics["frame_accuracy"]  # the labelled ones, scored as alone
    phases = new.filter(pl.col("trial") == 101)["phase"].to_list()
    runs = [(k, phases[k]) for k in range(len(phases)) if k == 0 or phases[k] != phases[k - 1]]
    rows = [f"b/201,{a},{b - 1},{name}" for (a, name), (b, _) in zip(runs, [*runs[1:], (len(phases), None)])]
    (tmp_path / "labels.csv").write_text("\n".join(["episode,start,end,label", *rows]) + "\n")
    labelled = predict.run(predict.PredictOptions(model=model, source=folder, output=tmp_path / "q.parquet",
                                                  reading=ReadOptions(overrides={"labels": tmp_path / "labels.csv"})))
    assert (labelled.metrics["recordings"], labelled.metrics["of"]) == (3, 4)  # the file's, and a.csv's own
    found = explain.run(explain.ExplainOptions(model=model, source=folder, episode="b/202", frame=10))
    assert found.episode == "b/202" and found.explanation.frame == 10
