"""Fixtures of the sweep tests: a tiny DESK dataset workdir with fold weights, and sweep files over it."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
TEST_FRAMES = 1500  # the DESK test split's first frames kept (all 1,405 training frames are)


@pytest.fixture(scope="session")
def tiny_desk_workdir(tmp_path_factory, desk_frames_workdir) -> Path:
    """DESK's training recording and the first 1,500 test frames, their predicates, examples/temporal.mln and its
    weights learned with 3 folds (`learn-weights --folds 3`): a dataset workdir a sweep runs on; read-only."""
    import polars as pl

    from mlnseq import binarize, formulas, learn_weights
    from mlnseq.catalog import artifacts

    workdir = tmp_path_factory.mktemp("tiny-desk")
    frames, meta = artifacts.read_table(desk_frames_workdir / artifacts.FRAMES, "frames")
    test_rows = frames.filter(pl.col("split") == "test").head(TEST_FRAMES)
    tiny = pl.concat([frames.filter(pl.col("split") == "train"), test_rows])
    artifacts.write_table(tiny, workdir / artifacts.FRAMES, "frames", artifacts.own_metadata(meta))
    binarize.run(workdir, binarize.BinarizeOptions())
    formulas.run(workdir, formulas.FormulasOptions(spec=REPO / "examples" / "temporal.mln"))
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions(folds=3))
    return workdir


@pytest.fixture(scope="session")
def local_sweep(tmp_path_factory, tiny_desk_workdir) -> dict:
    """The tiny sweep (2 cells x 2 seeds, 1 epoch) run locally with --cores 2: interrupted with Ctrl-C (SIGINT to
    its process group) once its first network is trained; resumed, and one of cell-tcn's jobs killed (SIGKILL) as
    it runs; then run again to the end; read-only."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import polars as pl

    from sweep_files import TINY_GRID, kill_a_job, mlnseq, write_sweep

    folder = tmp_path_factory.mktemp("local-sweep")
    path = write_sweep(folder, tiny_desk_workdir, TINY_GRID)
    command = [str(Path(sys.executable).with_name("mlnseq")), "sweep", str(path), "--cores", "2"]
    process = subprocess.Popen(command, cwd=folder, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True,  # hears Ctrl-C even when the tests run in the background:
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    out = folder / "sweep"
    deadline = time.monotonic() + 600
    while not finished_trainings(out) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    if process.poll() is not None:
        pytest.fail(f"the sweep ended (exit {process.returncode}) before a training finished: "
                    f"{process.communicate()[1][-3000:]}")
    os.killpg(process.pid, signal.SIGINT)
    interrupted_out, interrupted_err = process.communicate(timeout=120)
    if process.returncode == 0:
        pytest.fail("the sweep ran to its end: Ctrl-C reached it after its last job")
    finished = {out / p: (out / p).stat().st_mtime_ns for p in finished_trainings(out)}
    started = time.monotonic()
    resumed = subprocess.Popen(command, cwd=folder, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)
    try:
        killed_job = kill_a_job(resumed.pid, "cell-tcn", running=lambda: resumed.poll() is None)
    finally:
        killed_out, killed_err = resumed.communicate(timeout=600)
    killed = {"code": resumed.returncode, "stdout": killed_out, "stderr": killed_err, "job": killed_job,
              "table": pl.read_parquet(out / "results.parquet"), "log": (out / "sweep.log").read_text(),
              "files": {p: p.stat().st_mtime_ns for p in out.glob("runs/*/seed-*/**/*") if p.is_file()}}
    again = mlnseq("sweep", str(path), "--cores", "2", cwd=folder)
    return {"folder": folder, "path": path, "out": folder / "sweep", "interrupted": process.returncode,
            "interrupted_stderr": interrupted_err, "finished_before": finished, "killed": killed, "result": again,
            "log": (out / "sweep.log").read_text(), "seconds": time.monotonic() - started}


def finished_trainings(out: Path) -> list[str]:
    """The outputs of the train jobs Snakemake's log (OUT/.snakemake/log/) reports finished."""
    import re

    outputs, finished = {}, set()
    for log in out.glob(".snakemake/log/*.snakemake.log"):
        rule = output = None
        for line in log.read_text(errors="replace").splitlines():
            stripped = line.strip()
            if re.fullmatch(r"(local)?rule \w+:", stripped):
                rule, output = stripped.split()[-1][:-1], None
            elif rule == "train" and stripped.startswith("output: "):
                output = stripped.removeprefix("output: ")
            elif rule == "train" and stripped.startswith("jobid: ") and output:
                outputs[(log, stripped.removeprefix("jobid: "))] = output
            done = re.fullmatch(r"Finished jobid: (\d+) \(Rule: train\)", stripped)
            if done:
                finished.add((log, done.group(1)))
    return sorted(outputs[key] for key in finished if key in outputs)
