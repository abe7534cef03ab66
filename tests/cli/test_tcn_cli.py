"""The causal TCN through the README tour in stream mode: `train --cell tcn --mode stream` (alone and with the
PriorLayer, with MS-TCN's smoothing loss), conflate, export, predict and `mlnseq stream` on the real DESK data;
the model file recognises the test recording as conflate did, and the stream equals predict frame by frame."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts
from mlnseq import networks, predict
from mlnseq.recognition.recognizer import Recognizer

MLNSEQ = str(Path(sys.executable).parent / "mlnseq")
FRAMES = 1000  # of the DESK test recording, through the pipe
runner = CliRunner()


def invoke(*args):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result


@pytest.fixture(scope="module")
def tcn_workdir(tmp_path_factory, desk_stream_workdir) -> Path:
    workdir = tmp_path_factory.mktemp("tcn")
    for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS):
        shutil.copy(desk_stream_workdir / name, workdir / name)
    for method in ("lstm", "priorlayer"):
        invoke("train", "--method", method, "--cell", "tcn", "--mode", "stream", "--epochs", 2, "--select", "last",
               "--smoothing", 0.15, "-w", workdir)
    invoke("conflate", "--decode", "all", "-w", workdir)
    return workdir


@pytest.fixture(scope="module")
def recording(tmp_path_factory, desk_test_recording) -> Path:
    path = tmp_path_factory.mktemp("tcn-stream") / "head.csv"
    pl.read_csv(desk_test_recording).head(FRAMES).write_csv(path)
    return path


@pytest.mark.parametrize("name", ["lstm", "combined+filter"])
def test_a_tcn_model_file_recognises_the_test_recording_as_conflate_did(tcn_workdir, tmp_path, name):
    model_path = tmp_path / f"{name}.mlnseq"
    method, _, decode = name.partition("+")
    invoke("export", "--method", method, *(["--decode", decode] if decode else []), "--output", model_path,
           "-w", tcn_workdir)
    frames = pl.read_parquet(tcn_workdir / artifacts.FRAMES).filter(pl.col("split") == "test")
    expected = pl.read_parquet(tcn_workdir / artifacts.PREDICTIONS).filter(pl.col("split") == "test")
    model = Recognizer.load(model_path)
    assert model.manifest.network.model["cell"] == "tcn"
    probabilities, predicted = model.predict(frames.select(model.features).to_numpy())
    np.testing.assert_allclose(probabilities, expected.select(artifacts.prob_columns(name, 7)), atol=1e-5)
    assert (predicted == expected[artifacts.pred_column(name)].to_numpy()).all()
    shown = networks.describe(json.loads(invoke("info", "--json", model_path).output)["network"]["model"])
    assert shown == "tcn of 32 channels, kernel 3, 5 levels (receptive field 63 frames), smoothing 0.15"


def test_a_tcn_stream_equals_predict_frame_by_frame(tcn_workdir, recording, tmp_path):
    model = tmp_path / "combined+filter.mlnseq"
    invoke("export", "--method", "combined", "--decode", "filter", "--output", model, "-w", tcn_workdir)
    done = subprocess.run([MLNSEQ, "stream", str(model)], input=recording.read_text(), capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    answers = [json.loads(line) for line in done.stdout.splitlines()]
    expected = predict.run(predict.PredictOptions(model=model, source=recording, output=tmp_path / "p.parquet")).table
    assert len(answers) == FRAMES == expected.height
    assert [a["class"] for a in answers] == expected["class"].to_list()
    classes = list(answers[0]["probabilities"])
    got = np.array([[a["probabilities"][c] for c in classes] for a in answers])
    np.testing.assert_allclose(got, expected.select(artifacts.class_probability_column(c) for c in classes).to_numpy(), atol=1e-5)
