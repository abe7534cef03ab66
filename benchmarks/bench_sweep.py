"""Sweep speed: `mlnseq sweep --cores 2` (Snakemake running two stage commands at a time) against the same stage
commands run one after another, side by side in one run, on DESK (temporal.mln, weights with 3 folds, all 22,329
frames): a grid of 2 network types x 2 seeds; per config and seed the workdir linked to the dataset's inputs,
`train --mode stream` (the network and 3 fold networks), `conflate --decode all` (every decoder, cross-validated)
and `eval --method all`, as the sweep's Snakefile runs them, each with its output to a log file.

Printed per side: wall time and CPU time (user + system of every process it started), the ratio of the walls,
the difference of the CPU times (the sweep's own cost beyond the stage commands, `mlnseq sweep`'s and Snakemake's
start, DAG, scheduling and results table, about 2 s (bench_sweep_overhead measures it apart), plus the stage
commands' own variation from run to run, several seconds either way on about 200 s), the sweep's fixed cost
alone (`mlnseq sweep` run again with nothing to do), and the load average before and after.
Both sides must end with the same results table, which is checked. On 2 free cores the ratio approaches 2;
other work on the machine (the load average) lowers it. The stage commands are long enough that fixed start-up
does not dominate: most of the work is conflate's cross-validated decoding (about 45 s a config and seed).

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
from mlnseq.sweeps import grid, results, workflow
from mlnseq.pipeline.sweep import SWEPT as STAGES

REPO = Path(__file__).resolve().parents[1]
DESK_SOURCE = REPO.parent / "shared" / "data" / "desk-taurus"
CORES = 2


def dataset(folder: Path) -> Path:
    """DESK's frames, predicates, examples/temporal.mln and its weights with 3 folds."""
    workdir = folder / "desk"
    collect.run(workdir, collect.CollectOptions(env="desk", source=DESK_SOURCE))
    return with_weights(workdir)


def with_weights(workdir: Path) -> Path:
    """A workdir's frames made a sweep's dataset: their predicates, examples/temporal.mln and its weights with 3
    folds."""
    binarize.run(workdir, binarize.BinarizeOptions())
    formulas.run(workdir, formulas.FormulasOptions(spec=REPO / "examples" / "temporal.mln"))
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions(folds=3))
    return workdir


def one_after_another(sweep: grid.Sweep, out: Path, mlnseq: str) -> None:
    """The sweep's stage commands, as its Snakefile writes them, run in turn in OUT/runs/CONFIG/seed-N."""
    config = workflow.workflow_config(sweep, mlnseq)
    for name, flags in config["configs"].items():
        for seed in sweep.seeds:
            workdir = workflow.run_dir(out, name, seed)
            (workdir / "logs").mkdir(parents=True)
            for input_name, source in flags["sources"].items():
                (workdir / input_name).symlink_to(Path(source).resolve())
            commands = {f"train-{flags['network']}": f"train {flags['train']} --seed {seed}",
                        "conflate": f"conflate --decode all {flags['conflate']}", "eval": "eval --method all"}
            for log, command in commands.items():
                with open(workdir / "logs" / f"{log}.log", "w") as output:
                    subprocess.run([mlnseq, *shlex.split(command), "--workdir", str(workdir)], check=True,
                                   stdout=output, stderr=subprocess.STDOUT)


def children_cpu() -> float:
    """CPU seconds (user + system) of the finished child processes (and theirs) so far."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def timed(work) -> tuple[float, float]:
    """Wall and CPU seconds of ``work()``'s child processes."""
    cpu, started = children_cpu(), time.perf_counter()
    work()
    return time.perf_counter() - started, children_cpu() - cpu


def sweep_file(folder: Path, workdir: Path, epochs: int) -> grid.Sweep:
    """FOLDER/sweep.toml: 2 network types (lstm, tcn) x seeds 0 and 1 on ``workdir``, ``epochs`` each; read back."""
    path = folder / "sweep.toml"
    path.write_text(f'[sweep]\nworkdir = "{workdir}"\nseeds = [0, 1]\n\n[grid]\ncell = ["lstm", "tcn"]\n'
                    f"epochs = [{epochs}]\n")
    return grid.read(path, STAGES)


def main() -> None:
    epochs = int(os.environ.get("BENCH_SWEEP_EPOCHS", "10"))
    mlnseq = str(Path(sys.executable).with_name("mlnseq"))
    with tempfile.TemporaryDirectory() as name:
        folder = Path(name)
        workdir = dataset(folder)
        sweep = sweep_file(folder, workdir, epochs)
        load = os.getloadavg()[0]
        command = [mlnseq, "sweep", str(sweep.path), "--cores", str(CORES), "--out", str(folder / "sweep")]
        swept, swept_cpu = timed(lambda: subprocess.run(command, check=True, capture_output=True))
        rerun, rerun_cpu = timed(lambda: subprocess.run(command, check=True, capture_output=True))
        serial, serial_cpu = timed(lambda: one_after_another(sweep, folder / "serial", mlnseq))
        after = os.getloadavg()[0]
        same = results.gather(sweep, folder / "sweep").drop("deploy").equals(
            results.gather(sweep, folder / "serial").drop("deploy"))
        print(f"sweep of 2 cells x 2 seeds on DESK ({epochs} epochs; 4 x train with 3 fold networks, conflate "
              f"--decode all, eval): mlnseq sweep --cores {CORES} {swept:.1f} s (CPU {swept_cpu:.1f} s), the same "
              f"commands one after another {serial:.1f} s (CPU {serial_cpu:.1f} s), ratio {serial / swept:.2f}x; "
              f"CPU difference {swept_cpu - serial_cpu:+.1f} s; the sweep's rerun with nothing to do {rerun:.1f} s "
              f"(CPU {rerun_cpu:.1f} s); same results table: {'yes' if same else 'NO'} "
              f"(load average {load:.1f} before, {after:.1f} after, on {os.cpu_count()} cores)")
        if not same:
            raise SystemExit("the sweep and the commands one after another gave different results tables")


if __name__ == "__main__":
    main()
