"""Sweep speed: `mlnseq sweep --cores 2` (Snakemake running two stage commands at a time) against the same stage
commands run one after another, side by side in one run, on DESK (temporal.mln, weights with 3 folds): a grid of
2 network types x 2 seeds, each `train --mode stream` (3 fold networks), `conflate --decode all` and `eval`.
On 2 free cores the ratio approaches 2; other work on the machine (its load average is printed) lowers it.

``BENCH_SWEEP_EPOCHS`` sets the epochs (default 10).
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mlnseq import binarize, collect, formulas, learn_weights
from mlnseq.sweeps import grid, workflow
from mlnseq_cli.sweep import STAGES

REPO = Path(__file__).resolve().parents[1]
DESK_SOURCE = REPO.parent / "shared" / "data" / "desk-taurus"
CORES = 2


def dataset(folder: Path) -> Path:
    """DESK's frames, predicates, examples/temporal.mln and its weights with 3 folds."""
    workdir = folder / "desk"
    collect.run(workdir, collect.CollectOptions(env="desk", source=DESK_SOURCE))
    binarize.run(workdir, binarize.BinarizeOptions())
    formulas.run(workdir, formulas.FormulasOptions(spec=REPO / "examples" / "temporal.mln"))
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions(folds=3))
    return workdir


def one_after_another(sweep: grid.Sweep, folder: Path, mlnseq: str) -> float:
    """The sweep's stage commands, as its Snakefile writes them, run in turn: the wall time."""
    config = workflow.workflow_config(sweep, mlnseq)
    started = time.perf_counter()
    for name, flags in config["configs"].items():
        for seed in sweep.seeds:
            workdir = folder / name / f"seed-{seed}"
            workdir.mkdir(parents=True)
            for input_name, source in flags["sources"].items():
                (workdir / input_name).symlink_to(source)
            for command in (f"train {flags['train']} --seed {seed}", f"conflate --decode all {flags['conflate']}",
                            "eval --method all"):
                subprocess.run([mlnseq, *shlex.split(command), "--workdir", str(workdir)], check=True,
                               capture_output=True)
    return time.perf_counter() - started


def children_cpu() -> float:
    """CPU seconds (user + system) of the finished child processes so far."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    epochs = int(os.environ.get("BENCH_SWEEP_EPOCHS", "10"))
    mlnseq = str(Path(sys.executable).with_name("mlnseq"))
    with tempfile.TemporaryDirectory() as name:
        folder = Path(name)
        workdir = dataset(folder)
        path = folder / "sweep.toml"
        path.write_text(f'[sweep]\nworkdir = "{workdir}"\nseeds = [0, 1]\n\n[grid]\ncell = ["lstm", "tcn"]\n'
                        f"epochs = [{epochs}]\n")
        sweep = grid.read(path, STAGES)
        load = os.getloadavg()[0]
        cpu, started = children_cpu(), time.perf_counter()
        subprocess.run([mlnseq, "sweep", str(path), "--cores", str(CORES), "--out", str(folder / "sweep")],
                       check=True, capture_output=True)
        swept, swept_cpu = time.perf_counter() - started, children_cpu() - cpu
        cpu = children_cpu()
        serial = one_after_another(sweep, folder / "serial", mlnseq)
        serial_cpu = children_cpu() - cpu
        print(f"sweep of 2 cells x 2 seeds on DESK ({epochs} epochs, 4 trainings with 3 fold networks, 4 conflate "
              f"and 4 eval): mlnseq sweep --cores {CORES} {swept:.1f} s (CPU {swept_cpu:.1f} s), the same commands "
              f"one after another {serial:.1f} s (CPU {serial_cpu:.1f} s), ratio {serial / swept:.2f}x (load "
              f"average {load:.1f} before, {os.getloadavg()[0]:.1f} after, on {os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
