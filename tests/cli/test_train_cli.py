"""train, conflate and eval through the CLI on the real DESK data, and their bad-input messages."""

import json
import shutil

import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from stages import artifacts

runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


@pytest.fixture
def workdir(tmp_path, desk_mln_workdir):
    for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS):
        shutil.copy(desk_mln_workdir / name, tmp_path / name)
    return tmp_path


def test_bare_pipeline_to_combined_json(workdir):
    result = invoke("eval", "-w", workdir)
    assert result.exit_code == 2 and "mlnseq conflate" in result.output
    assert invoke("train", "--epochs", 2, "-w", workdir).exit_code == 0
    trained = invoke("train", "--method", "priorlayer", "--epochs", 2, "-w", workdir)
    assert trained.exit_code == 0, trained.output
    assert artifacts.checkpoint_path(workdir, "priorlayer").exists()
    conflated = invoke("conflate", "-w", workdir)
    assert conflated.exit_code == 0, conflated.output
    result = invoke("eval", "--method", "combined", "--json", "-w", workdir)
    assert result.exit_code == 0, result.output
    scores = json.loads(result.output)
    assert list(scores) == ["combined"]
    assert 0 <= scores["combined"]["segment_accuracy"] <= 1 and 0 <= scores["combined"]["frame_accuracy"] <= 1
    assert len(scores["combined"]["per_class"]) == 7
    table = invoke("eval", "-w", workdir)
    assert table.exit_code == 0 and "conflation" in table.output
    metrics, _ = artifacts.read_table(workdir / artifacts.METRICS, "metrics")
    assert set(metrics["method"]) == {"lstm", "mln", "priorlayer", "conflation", "combined"}


def test_bad_input_is_one_line_and_exit_2(workdir, tmp_path_factory):
    cases = [
        (("train", "--mode", "video"), "--mode"),
        (("train", "--train-fraction", 0), "--train-fraction"),
        (("eval", "--fraction", 1.5), "--fraction"),
        (("eval", "--method", "hmm"), "--method"),
        (("train", "-w", tmp_path_factory.mktemp("empty")), "mlnseq collect"),
    ]
    for args, message in cases:
        if "-w" not in args:
            args = (*args, "-w", workdir)
        result = invoke(*args)
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output and "Traceback" not in result.output


def test_eval_of_a_method_absent_from_predictions_names_the_stage(workdir):
    assert invoke("conflate", "-w", workdir).exit_code == 0  # only the MLN: no model trained
    result = invoke("eval", "--method", "lstm", "-w", workdir)
    assert result.exit_code == 2
    assert "train --method lstm" in result.output
