"""train, conflate and eval through the CLI on the real DESK data, and their bad-input messages."""

import json
import os
import pty
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts

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
    quiet = invoke("eval", "--no-tables", "-w", workdir)
    assert quiet.exit_code == 0 and quiet.output.splitlines() == [f"eval: wrote {workdir / artifacts.METRICS}"]
    assert artifacts.read_table(workdir / artifacts.METRICS, "metrics")[0].equals(metrics)


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


def train_output(workdir, epochs: int, terminal: bool) -> str:
    """What `mlnseq train` prints into a pipe (as in Make's log) or onto a terminal (a pseudo-terminal)."""
    command = [sys.executable, "-m", "mlnseq_cli.main", "train", "--epochs", str(epochs), "-w", str(workdir)]
    env = {**os.environ, "COLUMNS": "160", "MLNSEQ_VERBOSE": "", "TERM": "xterm"}
    if not terminal:
        return subprocess.run(command, capture_output=True, text=True, env=env, check=True).stdout
    leader, follower = pty.openpty()
    process = subprocess.Popen(command, stdin=follower, stdout=follower, stderr=follower, env=env)
    os.close(follower)
    chunks = []
    while True:
        try:
            chunk = os.read(leader, 1 << 16)
        except OSError:  # the terminal closed with the process
            break
        if not chunk:
            break
        chunks.append(chunk)
    os.close(leader)
    assert process.wait() == 0
    return b"".join(chunks).decode("utf-8", "replace")


def test_training_progress_in_a_log_is_a_line_per_tenth_of_the_epochs(workdir):
    out = train_output(workdir, 20, terminal=False)
    lines = [line for line in out.splitlines() if line.startswith("training lstm")]
    assert [line.split(": epoch ")[1].split(",")[0] for line in lines] == [f"{e}/20" for e in range(2, 21, 2)]
    # measured after the last epoch only (train's default --measure last-epoch): said once, on the first line
    assert "measured after the last epoch (--measure every-epoch: after each)" in lines[0]
    assert all("measure" not in line and " s left" in line for line in lines[1:-1]) and " s left" in lines[0]
    assert all(part in lines[-1] for part in ("loss ", "train ", "val –", " s left"))
    assert "\r" not in out and "\x1b" not in out


def test_training_progress_on_a_terminal_is_a_bar(workdir):
    out = train_output(workdir, 3, terminal=True)
    assert "\x1b[" in out  # drawn and redrawn in place
    plain = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", out)
    for epoch in (1, 2, 3):
        assert f"training lstm (segment mode): epoch {epoch}/3" in plain
    assert "loss " in plain and "train: wrote" in plain


def test_method_network_is_the_network_alone_stored_as_lstm(workdir, tmp_path):
    """--method network trains, scores and exports what --method lstm does (the name artifacts keep)."""
    trained = invoke("train", "--method", "network", "--epochs", 1, "--mode", "stream", "-w", workdir)
    assert trained.exit_code == 0, trained.output
    assert artifacts.checkpoint_path(workdir, "lstm").exists() and not (workdir / "models" / "network.pt").exists()
    assert invoke("conflate", "-w", workdir).exit_code == 0
    by_alias, by_name = (invoke("eval", "--method", name, "--json", "-w", workdir) for name in ("network", "lstm"))
    assert by_alias.exit_code == 0, by_alias.output
    assert list(json.loads(by_alias.output)) == ["lstm"] and json.loads(by_alias.output) == json.loads(by_name.output)
    exported = invoke("export", "--method", "network", "-o", tmp_path / "n.mlnseq", "-w", workdir)
    assert exported.exit_code == 0, exported.output
    shown = invoke("info", "--json", tmp_path / "n.mlnseq")
    assert json.loads(shown.output)["method"] == "lstm" and json.loads(shown.output)["paper_floor"] == "clamp"
    refused = invoke("train", "--method", "transformer", "-w", workdir)
    assert refused.exit_code == 2 and "choose one of network, lstm, priorlayer" in refused.stderr


def test_seeds_side_by_side_write_each_workdir_what_its_seed_trains_alone(workdir, tmp_path_factory):
    """`train --seed 0 -w A --seed 1 -w B` (each dataset's seeds in `make reproduce`): each workdir its own checkpoint,
    log and out-of-fold predictions, its seed recorded, the networks its seed trains alone up to float32 rounding;
    different inputs refused."""
    import torch

    other, alone = tmp_path_factory.mktemp("seed-1"), tmp_path_factory.mktemp("seed-1-alone")
    for folder in (other, alone):
        shutil.copy(workdir / artifacts.FRAMES, folder / artifacts.FRAMES)
    stream = ("--mode", "stream", "--folds", 2, "--epochs", 2)
    together = invoke("train", *stream, "--seed", 0, "-w", workdir, "--seed", 1, "-w", other)
    assert together.exit_code == 0, together.output
    assert together.output.count("train: wrote") == 2 and "seeds 0, 1 side by side" in together.output
    assert invoke("train", *stream, "--seed", 1, "-w", alone).exit_code == 0
    checkpoints = [torch.load(artifacts.checkpoint_path(w, "lstm"), weights_only=True) for w in (workdir, other, alone)]
    assert [c["config"]["seed"] for c in checkpoints] == [0, 1, 1]
    for name, value in checkpoints[2]["state_dict"].items():
        torch.testing.assert_close(checkpoints[1]["state_dict"][name], value, rtol=0, atol=1e-5, msg=name)
    assert (checkpoints[0]["state_dict"]["h2c.weight"] - checkpoints[1]["state_dict"]["h2c.weight"]).abs().max() > 0.01
    assert artifacts.train_log_path(other, "lstm").exists()
    out_of_fold = [artifacts.read_table(artifacts.out_of_fold_path(w, "lstm"))[0] for w in (workdir, other, alone)]
    lp = [c for c in out_of_fold[0].columns if c.startswith("lp")]
    np.testing.assert_allclose(out_of_fold[1].select(lp).to_numpy(), out_of_fold[2].select(lp).to_numpy(), atol=1e-4)
    assert not out_of_fold[0].select(lp).equals(out_of_fold[1].select(lp))

    frames, meta = artifacts.read_table(other / artifacts.FRAMES, "frames")
    artifacts.write_table(frames.head(frames.height - 1), other / artifacts.FRAMES, "frames", meta)
    refused = invoke("train", "--epochs", 1, "--seed", 0, "-w", workdir, "--seed", 1, "-w", other)
    assert refused.exit_code == 2 and "its inputs differ" in refused.stderr, refused.output
    unpaired = invoke("train", "--epochs", 1, "--seed", 0, "--seed", 1, "-w", workdir)
    assert unpaired.exit_code == 2 and "one distinct seed per workdir" in unpaired.stderr
