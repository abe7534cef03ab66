"""Live recognition: the Python API's per-frame latency, the `mlnseq stream` pipe's throughput, and resident
memory over a long stream.

A DESK workdir is built once (the real motion files, the paper's predicates, examples/temporal.mln learned
on the training split, lstm and priorlayer trained 3 epochs in stream mode with a validation part) and its
``combined`` method exported with ``--decode filter``. Then, side by side in this run:

- API: ``Recognizer.step`` on every frame of the 20,924-frame DESK test recording; p50 and p99 per frame
  (target p99 < 1 ms);
- CLI: ``mlnseq stream`` fed that recording as CSV through a pipe five times over (104,620 frames); frames
  per second after start-up, the start-up measured with an empty input (target >= 5,000 frames/s);
- the same two for ``combined`` with the legal fixed-lag smoother at the live budget's lag (``smooth-legal@25``,
  issue 24): each API step also decides frame t - 25 from the 26 frames it holds; the stream decides the frames
  it reads together at once, their windows side by side;
- memory: 10^6 frames through the API (the recording replayed, a new episode each time); resident memory
  after the first 10^4 frames and at the end (target growth < 10 MB).

``BENCH_QUICK=1`` streams 10^5 frames instead of 10^6 and pipes the recording once.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import polars as pl

REPO = Path(__file__).resolve().parents[1]
DESK_SOURCE = REPO.parent / "shared" / "data" / "desk-taurus"
TEMPORAL = REPO / "examples" / "temporal.mln"
TARGET_P99_MS, TARGET_FPS, TARGET_GROWTH_MB = 1.0, 5000.0, 10.0


LAG = 25  # frames: DESK's live budget (issue 24)


def combined_model(folder: Path) -> tuple[Path, Path]:
    """A DESK workdir (stream-mode networks, 3 epochs) and its exported combined+filter model."""
    from mlnseq import binarize, collect, export, formulas, learn_weights, train

    workdir = folder / "work"
    collect.run(workdir, collect.CollectOptions(env="desk", source=DESK_SOURCE))
    binarize.run(workdir, binarize.BinarizeOptions())
    formulas.run(workdir, formulas.FormulasOptions(spec=TEMPORAL))
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions())
    for method in ("lstm", "priorlayer"):
        train.run(workdir, train.TrainOptions(method=method, mode="stream", epochs=3, select="val_accuracy"))
    model = export.run(workdir, export.ExportOptions(method="combined", decode="filter",
                                                     output=folder / "combined.mlnseq")).path
    return workdir, model


def build_model(folder: Path) -> tuple[dict[str, Path], pl.DataFrame]:
    """The exported combined+filter and combined+smooth-legal@LAG models and the DESK test recording's frames."""
    from mlnseq import conflate, export

    workdir, model = combined_model(folder)
    conflate.run(workdir, conflate.ConflateOptions(decode=("smooth-legal",), lags=(LAG,)))
    lagged = export.run(workdir, export.ExportOptions(method="combined", decode="smooth-legal", lag=LAG,
                                                      output=folder / "combined-lag.mlnseq")).path
    frames = pl.read_parquet(workdir / "frames.parquet").filter(pl.col("split") == "test")
    return {"combined+filter": model, f"combined+smooth-legal@{LAG}": lagged}, frames


def resident_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def api_latency(model: Path, features: np.ndarray, name: str) -> None:
    from mlnseq.recognition.recognizer import Recognizer

    recognizer = Recognizer.load(model)
    for frame in features[:500]:  # warm the caches of the evidence rows seen first
        recognizer.step(frame)
    recognizer.reset()
    times = []
    for frame in features:
        started = time.perf_counter()
        recognizer.step(frame)
        times.append(time.perf_counter() - started)
    p50, p99 = statistics.median(times) * 1000, float(np.percentile(times, 99)) * 1000
    verdict = "meets" if p99 < TARGET_P99_MS else "MISSES"
    print(f"API step, {name}: p50 {p50:.3f} ms, p99 {p99:.3f} ms, max {max(times) * 1000:.2f} ms per frame "
          f"over {len(features):,} frames ({verdict} the p99 < {TARGET_P99_MS:g} ms target)", flush=True)


def cli_throughput(model: Path, csv_text: str, repeats: int, name: str) -> None:
    mlnseq = str(Path(sys.executable).parent / "mlnseq")
    header, body = csv_text.split("\n", 1)
    text = header + "\n" + body * repeats
    frames = body.count("\n") * repeats

    def timed(stdin: str) -> tuple[float, int]:
        started = time.perf_counter()
        done = subprocess.run([mlnseq, "stream", str(model)], input=stdin, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(done.stderr[-500:])
        return time.perf_counter() - started, done.stdout.count("\n")

    start_up, _ = timed("")
    seconds, answered = timed(text)
    fps = frames / (seconds - start_up)
    verdict = "meets" if fps >= TARGET_FPS else "MISSES"
    print(f"CLI stream, {name}: {answered:,} frames answered in {seconds:.1f} s incl. {start_up:.2f} s "
          f"start-up: {fps:,.0f} frames/s ({verdict} the {TARGET_FPS:,.0f} frames/s target)", flush=True)


def memory(model: Path, features: np.ndarray, total: int) -> None:
    from mlnseq.recognition.recognizer import Recognizer

    recognizer = Recognizer.load(model)
    done, after_warmup = 0, None
    while done < total:
        recognizer.reset()
        for frame in features[: total - done]:
            recognizer.step(frame)
            done += 1
            if done == 10_000:
                after_warmup = resident_mb()
    growth = resident_mb() - after_warmup
    verdict = "meets" if growth < TARGET_GROWTH_MB else "MISSES"
    print(f"memory over {total:,} frames: {after_warmup:.0f} MB after 10,000 frames, growth {growth:+.1f} MB "
          f"by the end ({verdict} the < {TARGET_GROWTH_MB:g} MB target)", flush=True)


def main() -> None:
    quick = os.environ.get("BENCH_QUICK", "") not in ("", "0")
    with tempfile.TemporaryDirectory() as folder:
        models, frames = build_model(Path(folder))
        features = frames.select("arm_distance", "left_gripper", "right_gripper").to_numpy()
        for name, model in models.items():
            api_latency(model, features, name)
            cli_throughput(model, frames.select("arm_distance", "left_gripper", "right_gripper").write_csv(),
                           1 if quick else 5, name)
        memory(models["combined+filter"], features, 100_000 if quick else 1_000_000)


if __name__ == "__main__":
    main()
