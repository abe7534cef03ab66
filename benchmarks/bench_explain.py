"""Explanations: what `stream --explain 3` costs a frame over `stream` at lag 0, and what `predict --explain 3` costs.

A DESK workdir is built once, as bench_recognize's (the real motion files, the paper's predicates, examples/temporal.mln
learned on the training split, lstm and priorlayer trained 3 epochs in stream mode with a validation part), and its
``combined`` method exported with ``--decode filter``. Then, side by side in this run, alternating, ROUNDS times:

- CLI: ``mlnseq stream MODEL`` and ``mlnseq stream MODEL --explain 3`` fed the 20,924-frame DESK test recording as CSV
  through a pipe; the cost of a frame's explanation is the difference of the two processes' CPU times (user + system:
  steadier than wall time on a loaded machine), each less its start-up (the same command fed the header alone), over
  the frames, median of the rounds (target < 50 us a frame);
- API: ``Recognizer.step`` over the recording with and without ``explain_steps(3)``, caches warm, CPU time: the same
  difference;
- CLI: ``mlnseq predict MODEL --source REC`` with and without ``--explain 3`` (a why column and the intervals' why),
  CPU seconds.

``BENCH_QUICK=1``: one round.
"""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import polars as pl

from benchmarks.bench_recognize import combined_model

FEATURES = ("arm_distance", "left_gripper", "right_gripper")
TARGET_US = 50.0
ROUNDS = 5


def build_model(folder: Path) -> tuple[Path, pl.DataFrame]:
    """The exported combined+filter model and the DESK test recording's frames."""
    workdir, model = combined_model(folder)
    return model, pl.read_parquet(workdir / "frames.parquet").filter(pl.col("split") == "test")


def timed(command: list[str], stdin: str | None = None) -> float:
    """The command's CPU seconds (user + system of the child: steadier than wall time on a loaded machine)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run(command, input=stdin, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(done.stderr[-500:])
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def api_difference(model: Path, features) -> tuple[float, float]:
    """Per-frame step time without and with explain_steps(3), best of 3 passes each, caches warm (us)."""
    from mlnseq.recognition.recognizer import Recognizer

    plain, explained = Recognizer.load(model), Recognizer.load(model)
    explained.explain_steps(3)
    best = {}
    for name, recognizer in (("plain", plain), ("explained", explained)):
        for frame in features:
            recognizer.step(frame)
    for _ in range(3):
        for name, recognizer in (("plain", plain), ("explained", explained)):
            recognizer.reset()
            started = time.process_time()
            for frame in features:
                recognizer.step(frame)
            best[name] = min(best.get(name, float("inf")), (time.process_time() - started) / len(features) * 1e6)
    return best["plain"], best["explained"]


def main() -> None:
    rounds = 1 if os.environ.get("BENCH_QUICK", "") not in ("", "0") else ROUNDS
    mlnseq = str(Path(sys.executable).parent / "mlnseq")
    with tempfile.TemporaryDirectory() as folder:
        model, frames = build_model(Path(folder))
        csv = frames.select(FEATURES).write_csv()
        recording = Path(folder) / "desk-test.csv"
        frames.select("frame", "label", *FEATURES).write_csv(recording)
        costs, plain_command, explained_command = [], [mlnseq, "stream", str(model)], [mlnseq, "stream", str(model),
                                                                                        "--explain", "3"]
        for _ in range(rounds):  # each side less its start-up (an input of the header alone)
            plain = timed(plain_command, csv) - timed(plain_command, csv.split("\n", 1)[0] + "\n")
            explained = timed(explained_command, csv) - timed(explained_command, csv.split("\n", 1)[0] + "\n")
            costs.append((explained - plain) / frames.height * 1e6)
        cost = statistics.median(costs)
        verdict = "meets" if cost < TARGET_US else "MISSES"
        print(f"CLI stream --explain 3 over stream at lag 0, combined+filter, {frames.height:,} CSV lines: "
              f"{cost:+.1f} us a frame (median of {rounds}: {', '.join(f'{c:+.1f}' for c in costs)}; {verdict} the "
              f"< {TARGET_US:g} us target)", flush=True)
        plain, explained = api_difference(model, frames.select(FEATURES).to_numpy())
        print(f"API step, combined+filter: {plain:.1f} us a frame, {explained:.1f} us with explain_steps(3) "
              f"({explained - plain:+.1f} us)", flush=True)
        out = Path(folder) / "out"
        plain = timed([mlnseq, "predict", str(model), "--source", str(recording), "-o", f"{out}.a.parquet"])
        explained = timed([mlnseq, "predict", str(model), "--source", str(recording), "-o", f"{out}.b.parquet",
                           "--explain", "3", "--intervals", f"{out}.csv"])
        print(f"CLI predict, combined+filter, {frames.height:,} frames: {plain:.2f} s, {explained:.2f} s of CPU with "
              f"--explain 3 and --intervals (every frame and segment explained)", flush=True)


if __name__ == "__main__":
    main()
