"""Killing a stage (SIGKILL) or pressing Ctrl-C (SIGINT) never costs an artifact.

The stages run as real subprocesses of the CLI. ``tests/stall_driver.py`` runs the same CLI with one
hook that marks a known point (the simulation or the training loop running, or a temporary file half
written and the process hung there), so the kill lands where the test says, not at a lucky moment.
After each kill the previous artifacts are byte-identical, nothing but a hidden temporary file is
left, and the next run of the stage succeeds and removes that file.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts
from mlnseq.model import checkpoints

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
DRIVER = REPO / "tests" / "stall_driver.py"
WAIT_S = 120  # generous: a loaded 2-core CI box takes seconds just to import torch and MuJoCo
runner = CliRunner()


def snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*.tmp"))


def visible(files: dict[str, str]) -> dict[str, str]:
    """Without the hidden temporary files (.NAME.*.tmp) an interrupted atomic write leaves behind."""
    return {name: digest for name, digest in files.items() if not Path(name).name.startswith(".")}


def hear_ctrl_c() -> None:
    """A child that hears Ctrl-C even when the tests run in the background (where a shell ignores SIGINT)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(workdir: Path, *args, where: str | None = None) -> tuple[subprocess.Popen, Path]:
    """Start ``mlnseq ARGS -w WORKDIR`` (through the stall driver when ``where`` is given)."""
    marker = workdir.parent / f"{workdir.name}.marker"
    marker.unlink(missing_ok=True)
    cli = [sys.executable, "-m", "mlnseq_cli.main"] if where is None else [sys.executable, str(DRIVER), str(marker), where]
    env = {**os.environ, "MLNSEQ_VERBOSE": ""}
    process = subprocess.Popen([*cli, *map(str, args), "-w", str(workdir)], cwd=REPO, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=hear_ctrl_c)
    return process, marker


def wait_for(process: subprocess.Popen, marker: Path) -> None:
    deadline = time.monotonic() + WAIT_S
    while not marker.exists():
        if process.poll() is not None:
            out, err = process.communicate()
            pytest.fail(f"the stage ended (exit {process.returncode}) before the point to interrupt:\n{out}\n{err}")
        if time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"the stage did not reach the point to interrupt within {WAIT_S} s")
        time.sleep(0.05)


def kill(process: subprocess.Popen) -> None:
    assert process.poll() is None, "the stage had already ended: it was not interrupted"
    process.send_signal(signal.SIGKILL)
    process.communicate(timeout=WAIT_S)
    assert process.returncode == -signal.SIGKILL


def ok(*args) -> None:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output


@pytest.fixture
def fetch_workdir(tmp_path, fetch_frames_workdir) -> Path:
    return Path(shutil.copytree(fetch_frames_workdir, tmp_path / "work"))


@pytest.fixture
def desk_workdir(tmp_path, desk_full_workdir) -> Path:
    return Path(shutil.copytree(desk_full_workdir, tmp_path / "work"))


@pytest.mark.mujoco
def test_sigkill_while_collect_simulates_keeps_the_previous_frames(fetch_workdir):
    before = snapshot(fetch_workdir)
    process, marker = start(fetch_workdir, "collect", "--env", "fetch", "--episodes", 2000,
                            where="running:mlnseq.sources.fetch:demonstrate")
    wait_for(process, marker)
    kill(process)
    assert snapshot(fetch_workdir) == before
    ok("collect", "--env", "fetch", "--episodes", 3, "--seed", 1, "-w", fetch_workdir)
    ok("binarize", "-w", fetch_workdir)


@pytest.mark.mujoco
def test_sigkill_mid_write_of_frames_keeps_the_previous_frames(fetch_workdir):
    before = snapshot(fetch_workdir)
    process, marker = start(fetch_workdir, "collect", "--env", "fetch", "--episodes", 3, "--seed", 1,
                            where="parquet-write")
    wait_for(process, marker)
    kill(process)
    after = snapshot(fetch_workdir)
    assert visible(after) == before
    new_files = set(after) - set(before)
    assert len(new_files) == 1 and all(Path(n).name.startswith(".frames.parquet.") for n in new_files), new_files
    ok("binarize", "-w", fetch_workdir)  # the previous frames still read
    ok("collect", "--env", "fetch", "--episodes", 3, "--seed", 1, "-w", fetch_workdir)
    assert leftovers(fetch_workdir) == []  # the rerun removed the killed run's temporary file
    frames, meta = artifacts.read_table(fetch_workdir / artifacts.FRAMES, "frames")
    assert meta["seed"] == 1 and frames.height == 150


def test_plain_sigkill_of_collect_keeps_the_previous_frames(tmp_path, desk_frames_workdir, shared_data):
    """No hook at all: the real `mlnseq collect` killed a moment after it starts, then rerun."""
    workdir = Path(shutil.copytree(desk_frames_workdir, tmp_path / "work"))
    before = snapshot(workdir)
    process, _ = start(workdir, "collect", "--env", "fetch", "--episodes", 5000)
    time.sleep(3)
    kill(process)
    assert visible(snapshot(workdir)) == before
    ok("collect", "--env", "desk", "--source", shared_data / "desk-taurus", "-w", workdir)
    assert artifacts.read_table(workdir / artifacts.FRAMES, "frames")[0].height == 22_329


def test_sigkill_during_training_keeps_the_previous_model(desk_workdir):
    before = snapshot(desk_workdir)
    process, marker = start(desk_workdir, "train", "--epochs", 1000, "--measure", "every-epoch",
                            where="running:mlnseq.choosing.training_rows:predict_log_probs")
    wait_for(process, marker)  # the first epoch is done, the second is running
    kill(process)
    assert snapshot(desk_workdir) == before
    ok("conflate", "-w", desk_workdir)  # the previous model still loads and predicts
    ok("train", "--epochs", 1, "-w", desk_workdir)
    checkpoints.load_checkpoint(desk_workdir, "lstm")


def test_sigkill_mid_write_of_a_checkpoint_keeps_the_previous_model_and_log(desk_workdir):
    before = snapshot(desk_workdir)
    process, marker = start(desk_workdir, "train", "--epochs", 1, "--seed", 7, where="checkpoint-write")
    wait_for(process, marker)
    kill(process)
    after = snapshot(desk_workdir)
    assert visible(after) == before  # the model and its log both as they were
    leftovers_now = [Path(n).name for n in set(after) - set(before)]  # the hidden temp (and the temp's temp)
    assert leftovers_now and all(n.startswith(".") and n.endswith(".tmp") and "lstm.pt" in n for n in leftovers_now)
    ok("conflate", "-w", desk_workdir)
    assert len(leftovers(desk_workdir)) == len(leftovers_now)  # conflate leaves other artifacts' files alone
    ok("train", "--epochs", 1, "--seed", 7, "-w", desk_workdir)
    assert leftovers(desk_workdir) == []  # the temporary file and the temp's temp are gone
    assert checkpoints.load_checkpoint(desk_workdir, "lstm").config["seed"] == 7


def test_ctrl_c_during_training_exits_130_and_keeps_the_last_complete_model(desk_workdir):
    before = snapshot(desk_workdir)
    process, marker = start(desk_workdir, "train", "--epochs", 1000, "--measure", "every-epoch",
                            where="running:mlnseq.choosing.training_rows:predict_log_probs")
    wait_for(process, marker)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=WAIT_S)
    assert process.returncode == 130, (out, err)
    assert err.strip().splitlines() == ["error: interrupted; artifacts written before the interruption are intact"]
    assert "Traceback" not in out + err
    assert snapshot(desk_workdir) == before  # nothing half-written, no temporary file left
    checkpoint = checkpoints.load_checkpoint(desk_workdir, "lstm")
    assert checkpoint.config["options"]["epochs"] == 2  # the model of the last complete run
    ok("conflate", "-w", desk_workdir)
    ok("eval", "-w", desk_workdir)
