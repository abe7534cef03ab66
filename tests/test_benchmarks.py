"""`make bench` stays runnable: the quicker benchmarks run to their end at small sizes and print their last figure.
Their timings are the benchmarks' own business; nothing here is timed. (The Fetch collection, the learn-weights
engines, the recogniser, ROS and the sweeps have their own tests.)"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SMALL = {"BENCH_QUICK": "1", "BENCH_FETCH_EPISODES": "5", "BENCH_BAG_MINUTES": "1", "BENCH_LENGTH_FRAMES": "20000",
         "BENCH_STARTUP_ROUNDS": "1"}
LAST_FIGURE = {  # benchmark: the start of the line it prints last
    "audit": "audit: 1 row(s) measured",
    "collect": "desk import: 22,329 frames",
    "decode": "decode: the 25 lagged, posterior and legal decodings",
    "first_day": "first day: 1 dataset(s) measured",
    "labels": "labels: 1 arm(s) measured",
    "networks": "tcn ",
    "recordings": "peak memory:",
    "review": "review: ",  # its figure, or why it skipped (no chromium)
    "length": "| train: one stream epoch",
    "scale": "scale: 1 size(s) measured",
    "startup": "mlnseq --help:",
    "train": "fetch (5 episodes):",
}


@pytest.mark.slow
@pytest.mark.parametrize("name", LAST_FIGURE)
def test_a_benchmark_runs_to_its_end(name, repo_root):
    done = subprocess.run([sys.executable, "-m", "benchmarks", name], cwd=repo_root, env={**os.environ, **SMALL},
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.splitlines()[-1].startswith(LAST_FIGURE[name]), done.stdout[-2000:]
