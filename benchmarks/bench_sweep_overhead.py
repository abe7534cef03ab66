"""The sweep's own cost, measured apart from its stage commands: the sweep's Snakefile for 2 cells x 2 seeds
(1 epoch) on a small DESK dataset (the training recording and the first 1,500 test frames, as tests/stages/sweeps use)
run by Snakemake with `--cores 2`, each stage command through a shell wrapper that logs its own CPU time (bash's
``times``); Snakemake's CPU is the whole run's CPU less the stage commands'. Unlike a difference of two whole
runs (bench_sweep), this holds under load: only the 12 jobs' own CPU is subtracted.
"""

from __future__ import annotations

import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.bench_sweep import DESK_SOURCE, sweep_file, timed, with_weights
from mlnseq import collect
from mlnseq.pipeline import sweep as stage
from mlnseq.sweeps import workflow

TEST_FRAMES = 1500


def small_dataset(folder: Path) -> Path:
    """DESK's training recording and its first 1,500 test frames, with temporal.mln's weights over 3 folds."""
    import polars as pl

    from mlnseq.catalog import artifacts

    full, workdir = folder / "full", folder / "desk"
    collect.run(full, collect.CollectOptions(env="desk", source=DESK_SOURCE))
    frames, meta = artifacts.read_table(full / artifacts.FRAMES, "frames")
    small = pl.concat([frames.filter(pl.col("split") == "train"),
                       frames.filter(pl.col("split") == "test").head(TEST_FRAMES)])
    artifacts.write_table(small, workdir / artifacts.FRAMES, "frames", artifacts.own_metadata(meta))
    return with_weights(workdir)


def timing_wrapper(folder: Path, mlnseq: str, logs: Path) -> str:
    """A command that runs mlnseq, then writes bash's ``times`` (its own CPU, then its children's) to a file of
    its own in ``logs``."""
    wrapper = folder / "timed-mlnseq"
    wrapper.write_text(f'#!/bin/bash\n{shlex.quote(mlnseq)} "$@"\nstatus=$?\ntimes > {shlex.quote(str(logs))}/$$'
                       '\nexit $status\n')
    wrapper.chmod(0o755)
    return str(wrapper)


def seconds(text: str) -> float:
    """bash's ``times`` figure, e.g. 1m2.500s, in seconds."""
    minutes, _, rest = text.partition("m")
    return 60 * float(minutes) + float(rest.rstrip("s"))


def main() -> None:
    mlnseq = str(Path(sys.executable).with_name("mlnseq"))
    with tempfile.TemporaryDirectory() as name:
        folder = Path(name)
        workdir = small_dataset(folder)
        sweep, logs, out = sweep_file(folder, workdir, 1), folder / "stage-cpu", folder / "sweep"
        logs.mkdir()
        snakefile = workflow.write(sweep, out, timing_wrapper(folder, mlnseq, logs))
        command = stage.snakemake_command(snakefile, out, stage.SweepOptions(cores=2))
        wall, cpu = timed(lambda: subprocess.run(command, check=True, capture_output=True))
        jobs = [sum(map(seconds, log.read_text().splitlines()[1].split())) for log in logs.iterdir()]
        _, noop = timed(lambda: subprocess.run(command, check=True, capture_output=True))
        print(f"the sweep's Snakemake run, 2 cells x 2 seeds (1 epoch) on 1,405 + {TEST_FRAMES:,} DESK frames, "
              f"--cores 2: {wall:.1f} s, CPU {cpu:.1f} s, of which its {len(jobs)} stage commands {sum(jobs):.1f} s "
              f"and Snakemake {cpu - sum(jobs):.1f} s (with nothing left to do: {noop:.1f} s; per job "
              f"{(cpu - sum(jobs) - noop) / len(jobs):.2f} s)")


if __name__ == "__main__":
    main()
