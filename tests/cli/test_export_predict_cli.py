"""`mlnseq export`, `info` and `predict` through the CLI: the model file, what it holds, new recordings."""

from __future__ import annotations

import shutil
from pathlib import Path

import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts

runner = CliRunner()


@pytest.fixture(scope="module")
def workdir(tmp_path_factory, desk_stream_workdir) -> Path:
    return Path(shutil.copytree(desk_stream_workdir, tmp_path_factory.mktemp("cli") / "work"))


def test_export_then_info_then_predict(workdir, desk_test_recording, tmp_path):
    done = runner.invoke(app, ["export", "--method", "conflation", "-w", str(workdir)])
    assert done.exit_code == 0, done.output
    model = workdir / "conflation.mlnseq"
    assert f"export: wrote {model} (conflation, decode none" in done.output
    shown = runner.invoke(app, ["info", str(model)])
    assert shown.exit_code == 0, shown.output
    for needle in ("conflation", "S1 approach peg", "arm_distance, left_gripper, right_gripper", "lstm: lstm of 32",
                   "stream mode", "frames.parquet"):
        assert needle in " ".join(shown.output.split()), needle  # a table cell may wrap
    out = tmp_path / "out.parquet"
    predicted = runner.invoke(app, ["predict", str(model), "--source", str(desk_test_recording), "-o", str(out)])
    assert predicted.exit_code == 0, predicted.output
    assert f"predict: wrote {out} (20,924 frames, 1 episode)\n" in predicted.output
    assert "labelled recordings" in predicted.output and "macro F1 (segments)" in predicted.output
    table, meta = artifacts.read_table(out, "predicted")
    conflated = pl.read_parquet(workdir / artifacts.PREDICTIONS).filter(pl.col("split") == "test")
    classes = meta["classes"]
    assert table.height == conflated.height == 20_924
    assert table["frame"].to_list() == conflated["frame"].to_list()
    assert table["label"].to_list() == conflated["label"].to_list()
    assert table["class"].to_list() == [classes[k] for k in conflated[artifacts.pred_column("conflation")]]
    assert len(set(table["class"])) > 1  # a model that names one class everywhere would not test the order


@pytest.mark.parametrize(("args", "needle"), [
    (["export", "--method", "hmm"], "unknown --method 'hmm'"),
    (["export", "--decode", "blur"], "unknown --decode 'blur'"),
    (["export", "--decode", "smooth"], "--decode smooth waits a number of frames: give --lag FRAMES"),
    (["export", "--lag", "-1"], "--lag -1: a lag is at least 0 frames"),
    (["info", "absent.mlnseq"], "model file absent.mlnseq not found"),
    (["predict", "absent.mlnseq", "--source", "x.csv"], "model file absent.mlnseq not found"),
])
def test_bad_usage_is_one_line_and_exit_2(workdir, args, needle):
    done = runner.invoke(app, args if args[0] != "export" else [*args, "-w", str(workdir)])
    assert done.exit_code == 2, done.output
    assert done.stderr.strip().count("\n") == 0 and needle in done.stderr


def test_predict_cli_counts_the_restarts_in_its_summary(own_data_glitch, tmp_path):
    done = CliRunner().invoke(app, ["predict", str(own_data_glitch["model"]), "--source", str(own_data_glitch["csv"]),
                                    "-o", str(tmp_path / "o.parquet"), "--episode-column", "trial",
                                    "--time-column", "t", "--label-column", "phase"])
    assert done.exit_code == 0, done.output
    text = " ".join(done.output.split())
    assert f"episode 11 frame {own_data_glitch['frame']}" in text and "1 chain restart)" in text
