"""Start-up: `mlnseq --help`, a command's help and two light stages (binarize and formulas on the DESK
frames), each a fresh process as a user starts it, and the two stages again through scripts/stage_server.py as
`make reproduce` runs them, beside two references run in the same rounds: `python -c pass` and a bare typer
app's `--help`. Every command runs once per round, rounds alternate; medians of wall and CPU (user + system)
seconds of the command's own process (a served stage's CPU is the server's child's, not counted). Target:
`mlnseq --help` within 1.5x the bare typer app.

``BENCH_STARTUP_ROUNDS`` sets the number of rounds (default 7).
"""

from __future__ import annotations

import contextlib
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from mlnseq import binarize, collect, formulas

TARGET_HELP_RATIO = 1.5
DESK_SOURCE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "desk-taurus"
STAGE_SERVER = Path(__file__).resolve().parents[1] / "scripts" / "stage_server.py"
BARE_TYPER_APP = '''
import typer

app = typer.Typer(rich_markup_mode="rich", add_completion=False)


@app.command()
def first(workdir: str = "work") -> None:
    """A command."""


@app.command()
def second(epochs: int = 1) -> None:
    """Another command."""


app()
'''


def mlnseq_command() -> list[str]:
    script = Path(sys.executable).parent / "mlnseq"
    return [str(script)] if script.exists() else [sys.executable, "-m", "mlnseq_cli.main"]


def timed(command: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds of one run of ``command`` (its output discarded)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


@contextlib.contextmanager
def stage_server(socket_path: Path) -> Iterator[None]:
    """scripts/stage_server.py listening at ``socket_path`` (its first request waits for its imports)."""
    server = subprocess.Popen([sys.executable, str(STAGE_SERVER), "serve", str(socket_path)])
    try:
        while not socket_path.exists():
            if server.poll() is not None:
                raise SystemExit("the stage server did not start")
            time.sleep(0.05)
        yield
    finally:
        server.terminate()
        server.wait()


def main() -> None:
    rounds = int(os.environ.get("BENCH_STARTUP_ROUNDS", "7"))
    mlnseq = mlnseq_command()
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        bare = folder / "bare_typer_app.py"
        bare.write_text(BARE_TYPER_APP)
        commands = {
            "python -c pass": [sys.executable, "-c", "pass"],
            "bare typer app --help": [sys.executable, str(bare), "--help"],
            "mlnseq --help": [*mlnseq, "--help"],
            "mlnseq train --help": [*mlnseq, "train", "--help"],
        }
        socket_path = folder / "stages.sock"
        if DESK_SOURCE.is_dir():
            workdir = folder / "desk"
            collect.run(workdir, collect.CollectOptions(env="desk", source=DESK_SOURCE))
            binarize.run(workdir, binarize.BinarizeOptions())
            formulas.run(workdir, formulas.FormulasOptions())
            served = [sys.executable, str(STAGE_SERVER), "run", str(socket_path), *mlnseq]
            for stage in ("binarize", "formulas"):
                commands[f"mlnseq {stage} (DESK)"] = [*mlnseq, stage, "-w", str(workdir)]
                if len(mlnseq) == 1:  # the server runs the mlnseq script's commands
                    commands[f"  {stage}, stage server"] = [*served, stage, "-w", str(workdir)]
        with stage_server(socket_path):
            for command in commands.values():  # warm the file cache and the bytecode
                timed(command)
            runs: dict[str, list[tuple[float, float]]] = {name: [] for name in commands}
            for _ in range(rounds):
                for name, command in commands.items():
                    runs[name].append(timed(command))
    wall = {name: statistics.median(w for w, _ in r) for name, r in runs.items()}
    cpu = {name: statistics.median(c for _, c in r) for name, r in runs.items()}
    print(f"start-up, median of {rounds} alternating rounds (wall s / cpu s):")
    for name in commands:
        print(f"  {name:28s} {wall[name]:6.3f} / {cpu[name]:6.3f}")
    ratio = wall["mlnseq --help"] / wall["bare typer app --help"]
    cpu_ratio = cpu["mlnseq --help"] / cpu["bare typer app --help"]
    verdict = "meets" if ratio <= TARGET_HELP_RATIO else "MISSES"
    print(f"mlnseq --help: {ratio:.2f}x the bare typer app's wall time ({cpu_ratio:.2f}x its cpu), {verdict} the "
          f"{TARGET_HELP_RATIO:g}x target")


if __name__ == "__main__":
    main()
