"""learn-weights speed: native BPLL against pracmln on the DESK training split, and native's growth.

Each run is a subprocess (one BLAS thread) that reports its learning time and peak resident
memory. Data: the authors' published motion codes with the paper's predicates (arm distance,
left, right and the gripper pair). Sizes: the 1,405 DESK training frames (native and pracmln,
same weights: max |diff| printed); all 22,329 DESK frames; 200,000 Fetch-like frames made by
tiling the published Fetch train and test codes (native only). Target: native >= 1,000x faster.
``BENCH_QUICK=1`` uses the first 200 DESK training frames and 20,000 Fetch-like frames.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import polars as pl

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
TARGET_RATIO = 1000.0


def fetch_like(frames: int) -> pl.DataFrame:
    """The published Fetch gripper codes (train, then test) tiled to ``frames`` frames, all training."""
    from stages.mln.published_codes import FETCH_GRIPPER, one_hot, predicates_table

    codes = np.concatenate([np.loadtxt(DATA / "gym-fetch-v1" / name) for name in
                            ("fetch_motion_train.txt", "fetch_motion_test.txt")]).astype(np.int64)
    codes = np.tile(codes, (frames // len(codes) + 1, 1))[:frames]
    table, _ = predicates_table({"gripper": one_hot(codes[:, 0], "gripper", FETCH_GRIPPER)}, codes[:, 1],
                                np.array(["train"] * frames), np.zeros(frames, dtype=np.int64))
    return table


def dataset(name: str, train_limit: int) -> tuple[pl.DataFrame, int]:
    from stages.mln.published_codes import desk_predicates

    if name == "desk-train":
        return desk_predicates(DATA, train_limit=train_limit)[0], 7
    if name == "desk-all":
        return desk_predicates(DATA)[0].with_columns(pl.lit("train").alias("split")), 7
    return fetch_like(train_limit), 4


def worker(engine: str, name: str, size: int) -> None:
    """In the subprocess: learn once, print one JSON line."""
    from stages import learn_weights
    from stages.formulas import DEFAULT_SPEC, read_spec

    table, n_classes = dataset(name, size)
    mln = read_spec(DEFAULT_SPEC)
    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    started = time.perf_counter()
    weights = learn_weights.learn(table, n_classes, mln, engine).weights
    seconds = time.perf_counter() - started
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"seconds": seconds, "peak_mb": peak, "baseline_mb": baseline,
                      "frames": table.filter(pl.col("split") == "train").height,
                      "formulas": weights["formula"].to_list(), "weights": weights["weight"].to_list()}))


def measure(engine: str, name: str, size: int) -> dict:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-m", "benchmarks.bench_learn_weights", engine, name, str(size)],
                          capture_output=True, text=True, env=env, cwd=Path(__file__).resolve().parents[1])
    if done.returncode != 0:
        raise RuntimeError(f"{engine} on {name} failed: {done.stderr.strip()[-500:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    print(f"  {engine:8s} {name:10s} {result['frames']:>8,} frames  {result['seconds']:9.3f} s  "
          f"peak RSS {result['peak_mb']:6.0f} MB (after loading {result['baseline_mb']:.0f} MB)", flush=True)
    return result


def main() -> None:
    quick = os.environ.get("BENCH_QUICK", "") not in ("", "0")
    desk_frames = 200 if quick else 1405
    native = measure("native", "desk-train", desk_frames)
    pracmln = measure("pracmln", "desk-train", desk_frames)
    by_formula = dict(zip(pracmln["formulas"], pracmln["weights"]))
    ours, theirs = np.array(native["weights"]), np.array([by_formula[f] for f in native["formulas"]])
    small = (np.abs(ours) < 10) & (np.abs(theirs) < 10)
    ratio = pracmln["seconds"] / native["seconds"]
    verdict = "meets" if ratio >= TARGET_RATIO else "MISSES"
    print(f"learn-weights: native {ratio:,.0f}x faster than pracmln on {desk_frames:,} DESK training frames "
          f"({verdict} the {TARGET_RATIO:,.0f}x target); memory {pracmln['peak_mb'] / native['peak_mb']:.1f}x less")
    print(f"learn-weights: weights under 10: max |native - pracmln| = {np.abs(ours - theirs)[small].max():.2e} "
          f"({small.sum()} of {len(ours)}); all: {np.abs(ours - theirs).max():.3f}; same sign for the rest: "
          f"{bool((np.sign(ours) == np.sign(theirs))[~small].all())}")
    measure("native", "desk-all", 0)
    measure("native", "fetch-like", 20_000 if quick else 200_000)


if __name__ == "__main__":
    if len(sys.argv) == 4:
        worker(sys.argv[1], sys.argv[2], int(sys.argv[3]))
    else:
        main()
