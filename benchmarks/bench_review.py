"""`mlnseq review`: how long a 10-minute recording at 100 Hz with 22 channels takes to draw in the browser.

The generated 7-joint arm of tests/arm_bags.py (positions, velocities and efforts of 7 joints and the gripper's
width: 22 channels) at 100 Hz: four episodes fitted as an MLN filter model (its hand-written spec from the arm's data
sheet, examples/temporal.mln learned; no network, so no torch), and 60,000 frames of further episodes, end to end,
as one recording (a Parquet table). `mlnseq review` serves it; Debian's headless chromium (tests/review_browser.py)
opens the page, and the page measures, with its own clock, from asking for the recording to its 22 channel plots,
the probability line and the phase bands drawn (two animation frames after the last plot is made). Printed: that
time (target < 2 s), the page's whole load from navigation, and how long review took to read and decide the
recording before serving it. ``BENCH_QUICK=1``: one round, else the median of 3 page loads.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import polars as pl

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))  # the arm's generator and the browser driver of the tests
RATE = 100.0
MINUTES = 10
TARGET_S = 2.0


def arm_table(seeds: range, frames: int | None = None) -> pl.DataFrame:
    """Episodes of the arm at RATE as a table: episode, t, the 22 channels, phase; ``frames``: the episodes end to
    end as one recording of that many frames."""
    import arm_bags

    robot = arm_bags.at_rate("panda", RATE)
    tables, total = [], 0
    for k, seed in enumerate(seeds):
        signals = arm_bags.episode_signals(robot, seed)
        n = len(signals["phase"])
        columns = {"/gripper/width/data": signals["width"]} | {
            f"/joint_states/{field}/{joint}": signals[field][:, j] for field in ("position", "velocity", "effort")
            for j, joint in enumerate(robot.joints)}
        tables.append(pl.DataFrame({"episode": np.full(n, 0 if frames else k), **columns,
                                    "phase": np.asarray(arm_bags.PHASES)[signals["phase"]]}))
        total += n
        if frames is not None and total >= frames:
            break
    table = pl.concat(tables).head(frames) if frames else pl.concat(tables)
    return table.with_columns(t=pl.int_range(pl.len()).over("episode") / RATE)


def model(folder: Path) -> Path:
    """The arm's MLN filter model (hand spec, examples/temporal.mln learned on four episodes)."""
    import arm_bags
    from mlnseq import binarize, collect, export, formulas, learn_weights
    from mlnseq.sources.recording import TableColumns

    source = folder / "fit.parquet"
    arm_table(range(4)).write_parquet(source)
    (folder / "arm.binarize.toml").write_text(arm_bags.hand_spec("panda"))
    workdir = folder / "work"
    columns = TableColumns(label="phase", episode="episode", time="t")
    collect.run(workdir, collect.CollectOptions(env="table", source=source, columns=columns))
    binarize.run(workdir, binarize.BinarizeOptions(spec=folder / "arm.binarize.toml"))
    formulas.run(workdir, formulas.FormulasOptions(spec=REPO / "examples" / "temporal.mln"))
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions())
    return export.run(workdir, export.ExportOptions(method="mln", decode="filter", output=folder / "arm.mlnseq")).path


def main() -> None:
    import os

    import review_browser

    why = review_browser.missing()
    if why is not None:
        print(f"review: skipped ({why})")
        return
    rounds = 1 if os.environ.get("BENCH_QUICK") else 3
    frames = int(MINUTES * 60 * RATE)
    with tempfile.TemporaryDirectory(prefix="bench-review-") as tmp:
        folder = Path(tmp)
        path = model(folder)
        recording = folder / "ten-minutes.parquet"
        arm_table(range(1000, 2000), frames).drop("phase").write_parquet(recording)
        started = time.monotonic()
        with review_browser.served(path, "--source", recording, "--save", folder / "labels.csv") as (url, _):
            ready = time.monotonic() - started
            drawn, loads, channels = [], [], 0
            with review_browser.browser() as page:
                for _ in range(rounds):
                    loads.append(review_browser.opened(page, url, timeout=60))
                    drawn.append(page.evaluate("window.review.drawnMs") / 1000)
                    channels = page.evaluate("window.review.plots.length - 1")
                assert page.errors == [], page.errors
    print(f"review: read and decided {frames:,} frames in {ready:.1f} s before serving")
    print(f"review: page loaded (navigation to drawn) in {statistics.median(loads):.2f} s, median of {rounds}")
    print(f"review: {frames:,} frames at {RATE:g} Hz x {channels} channels drawn in {statistics.median(drawn):.2f} s "
          f"in the browser (median of {rounds}; target < {TARGET_S:g} s)")


if __name__ == "__main__":
    main()
