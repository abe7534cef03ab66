"""Helpers of the sweep tests: sweep files, the mlnseq command as a process, a refusal's one line."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path


def write_sweep(folder: Path, workdir: Path, grid: str, seeds: str = "[0, 1]") -> Path:
    """A sweep file in ``folder`` over ``workdir`` with the [grid] lines ``grid``."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "sweep.toml"
    path.write_text(f'[sweep]\nworkdir = "{workdir}"\nseeds = {seeds}\n\n[grid]\n{grid}\n', encoding="utf-8")
    return path


TINY_GRID = 'cell = ["lstm", "tcn"]\nepochs = [1]\n'  # the tiny sweep: 2 cells x 2 seeds, 1 epoch


def mlnseq(*args: str, cwd: Path, env: dict[str, str] | None = None, timeout: int = 600) -> subprocess.CompletedProcess:
    """This installation's `mlnseq ARGS` as a process."""
    command = [str(Path(sys.executable).with_name("mlnseq")), *args]
    return subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)


def refused(result, *words: str) -> str:
    """The one stderr line of a run (a process or typer's CliRunner) refused with exit 2, checked to hold ``words``."""
    code = getattr(result, "returncode", getattr(result, "exit_code", None))
    assert code == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]

REPO = Path(__file__).resolve().parents[1]


def kill_a_job(group: int, config: str, stages: tuple[str, ...] = ("train", "conflate"), timeout: float = 600,
               running: Callable[[], bool] = lambda: True) -> str:
    """SIGKILL the first `mlnseq STAGE ... --workdir runs/CONFIG/...` of the process group ``group`` (a sweep started
    in a session of its own: only its jobs) once it runs, while ``running()``; its command line."""
    import os
    import signal
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and running():
        for pid in filter(str.isdigit, os.listdir("/proc")):
            try:
                words = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
                if os.getpgid(int(pid)) != group:
                    continue
            except OSError:  # gone meanwhile
                continue
            if any(w.endswith("mlnseq") for w in words[:2]) and any(s in words[:3] for s in stages) \
                    and any(w.startswith(f"runs/{config}/") for w in words):
                os.kill(int(pid), signal.SIGKILL)
                return " ".join(words)
        time.sleep(0.02)
    raise TimeoutError(f"no {' or '.join(stages)} job of {config} ran within {timeout:g} s, or before the sweep ended")
