"""predict on recordings unlike the model's own: the message says how to read them, and the predictions name
the true labels as the recording did. A real DESK model trained on the test split written as a lab's log."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq import collect, export, predict, train
from mlnseq.sources.desk import CLASSES as DESK_CLASSES
from mlnseq.sources.recording import TableColumns

runner = CliRunner()
TRIAL = 1500


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


@pytest.fixture(scope="module")
def log(desk_test_recording, tmp_path_factory) -> Path:
    frames = pl.read_csv(desk_test_recording).head(4 * TRIAL)
    path = tmp_path_factory.mktemp("lab-log") / "trials.csv"
    pl.DataFrame({"trial": [f"T{i // TRIAL}" for i in range(frames.height)],
                  "t": [(i % TRIAL) * 0.05 for i in range(frames.height)],
                  "phase": [DESK_CLASSES[k] for k in frames["label"]]}).hstack(
        frames.select("arm_distance", "left_gripper", "right_gripper")).write_csv(path)
    return path


@pytest.fixture(scope="module")
def model(log, tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("lab-work")
    collect.run(workdir, collect.CollectOptions(env="table", source=log, columns=TableColumns(
        label="phase", episode="trial", time="t")))
    train.run(workdir, train.TrainOptions(method="lstm", mode="stream", epochs=1))
    return export.run(workdir, export.ExportOptions(method="lstm")).path


def test_a_recording_without_the_remembered_episode_column_is_refused_with_the_way_to_read_it(model, log, tmp_path):
    bare = tmp_path / "bare.csv"
    pl.read_csv(log).drop("trial", "t").head(TRIAL).write_csv(bare)
    result = runner.invoke(app, ["predict", str(model), "--source", str(bare), "-o", str(tmp_path / "p.parquet")])
    assert result.exit_code == 2
    assert "no column 'trial', 't'" in result.stderr and "pass --episode-column '' --time-column ''" in result.stderr
    done = runner.invoke(app, ["predict", str(model), "--source", str(bare), "-o", str(tmp_path / "p.parquet"),
                               "--episode-column", "", "--time-column", ""])
    assert done.exit_code == 0, done.output


def test_named_labels_come_back_as_names_beside_the_predicted_class(model, log, tmp_path):
    result = predict.run(predict.PredictOptions(model=model, source=log, output=tmp_path / "p.parquet"))
    table = pl.read_parquet(tmp_path / "p.parquet")
    assert table["label"].dtype == table["class"].dtype == pl.String
    assert table["label"].to_list() == pl.read_csv(log)["phase"].to_list()
    assert result.metrics is not None


def test_predicted_intervals_of_trials_named_with_leading_zeros_read_back_as_labels(log, tmp_path):
    folder = tmp_path / "trials"
    folder.mkdir()
    table = pl.read_csv(log)
    for k, name in enumerate(("001", "002", "010")):
        table.slice(k * TRIAL, TRIAL).drop("trial", "t").write_csv(folder / f"{name}.csv")
    workdir = tmp_path / "work"
    collect.run(workdir, collect.CollectOptions(env="table", source=folder, columns=TableColumns(label="phase")))
    train.run(workdir, train.TrainOptions(method="lstm", mode="stream", epochs=1))
    model = export.run(workdir, export.ExportOptions(method="lstm")).path
    predicted = predict.run(predict.PredictOptions(model=model, source=folder, output=tmp_path / "p.parquet",
                                                   intervals=tmp_path / "p.csv"))
    assert predicted.table["episode"].unique(maintain_order=True).to_list() == ["001", "002", "010"]
    relabelled = collect.collect(collect.CollectOptions(env="table", source=folder, columns=TableColumns(label="phase"),
                                                        recordings=collect.SourceOptions(labels=tmp_path / "p.csv")))
    classes = relabelled.meta["classes"]
    assert [classes[k] for k in relabelled.frames["label"]] == predicted.table["class"].to_list()
