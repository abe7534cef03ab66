"""scripts/stage_server.py, which `make reproduce` runs its stages through: the same artifacts, output and exit
statuses as stages run as processes of their own (scripts/timed_stage.sh with and without the server)."""

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

pytestmark = pytest.mark.slow

EPOCH = "1700000000"


def snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def start_server(repo_root: Path, socket_path: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    process = subprocess.Popen([sys.executable, repo_root / "scripts" / "stage_server.py", "serve", socket_path],
                               env=env)
    deadline = time.monotonic() + 30
    while not socket_path.exists():
        assert process.poll() is None and time.monotonic() < deadline, "the server did not start"
        time.sleep(0.05)
    return process


def stop_server(process: subprocess.Popen, socket_path: Path) -> None:
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=30) == 0
    assert not socket_path.exists()


@pytest.fixture
def server(tmp_path, repo_root):
    """A stage server listening on a socket in ``tmp_path``; stopped after the test."""
    socket_path = tmp_path / "stages.sock"
    process = start_server(repo_root, socket_path)
    yield socket_path
    stop_server(process, socket_path)


def stage(repo_root: Path, runs: Path, *args, server: Path | None = None) -> subprocess.CompletedProcess:
    """One stage through scripts/timed_stage.sh, as `make reproduce` runs it."""
    env = {**os.environ, "SOURCE_DATE_EPOCH": EPOCH, "MLNSEQ_VERBOSE": ""}
    env.pop("MLNSEQ_STAGE_SERVER", None)
    if server is not None:
        env["MLNSEQ_STAGE_SERVER"] = str(server)
    mlnseq = Path(sys.executable).parent / "mlnseq"
    return subprocess.run(["bash", repo_root / "scripts" / "timed_stage.sh", runs, mlnseq, *map(str, args)],
                          cwd=repo_root, env=env, capture_output=True, text=True)


def without_times(text: str) -> list[str]:
    return [line.rsplit("  [", 1)[0] for line in text.splitlines()]


def test_stages_through_the_server_write_what_plain_processes_write(tmp_path, repo_root, shared_data, server):
    pipeline = [
        ("collect", "--env", "desk", "--source", shared_data / "desk-taurus"), ("binarize",), ("formulas",),
        ("learn-weights",), ("train", "--epochs", 2, "--seed", 3), ("train", "--method", "priorlayer", "--epochs", 2),
        ("conflate",), ("eval",),
    ]
    for args in pipeline:
        served = stage(repo_root, tmp_path / "runs-served", *args, "-w", tmp_path / "served", server=server)
        plain = stage(repo_root, tmp_path / "runs-plain", *args, "-w", tmp_path / "plain")
        assert served.returncode == plain.returncode == 0, served.stdout + served.stderr
        assert without_times(served.stdout.replace("served", "plain")) == without_times(plain.stdout), args
    assert snapshot(tmp_path / "served") == snapshot(tmp_path / "plain")
    assert len(snapshot(tmp_path / "served")) == 13  # 11 artifacts and the 2 networks' log-probability caches


def test_a_refused_stage_keeps_its_status_and_error_line(tmp_path, repo_root, server):
    done = stage(repo_root, tmp_path / "runs", "eval", "-w", tmp_path / "empty", server=server)
    assert done.returncode == 2
    assert "error: " in done.stdout and "predictions.parquet not found" in done.stdout
    assert "failed after" in done.stderr and "Traceback" not in done.stdout + done.stderr


def test_without_a_server_the_stage_runs_as_its_own_process(tmp_path, repo_root):
    done = stage(repo_root, tmp_path / "runs", "eval", "-w", tmp_path / "empty", server=tmp_path / "absent.sock")
    assert done.returncode == 2 and "predictions.parquet not found" in done.stdout


def test_a_stage_edited_while_the_server_runs_runs_as_edited(tmp_path, repo_root):
    package = tmp_path / "package" / "mlnseq"  # a copy of the stages, imported by the server ahead of the install
    shutil.copytree(repo_root / "stages", package)
    stage_file, artifacts = package / "eval.py", package / "catalog" / "artifacts.py"
    source = stage_file.read_text()
    stage_file.write_text(source + "\nraise RuntimeError('a broken stage')\n")  # while the server imports the stages
    socket_path = tmp_path / "stages.sock"
    process = start_server(repo_root, socket_path, env={**os.environ, "PYTHONPATH": str(package.parent)})
    try:
        broken = stage(repo_root, tmp_path / "runs", "eval", "-w", tmp_path / "empty", server=socket_path)
        stage_file.write_text(source)
        artifacts.write_text(artifacts.read_text().replace("} not found: run", "} not found (edited): run"))
        edited = stage(repo_root, tmp_path / "runs", "eval", "-w", tmp_path / "empty", server=socket_path)
    finally:
        stop_server(process, socket_path)
    assert broken.returncode == 1 and "RuntimeError: a broken stage" in broken.stdout
    assert edited.returncode == 2
    assert "predictions.parquet not found (edited): run" in edited.stdout
