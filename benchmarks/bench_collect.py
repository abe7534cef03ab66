"""Fetch collection speed: a 100-episode collection, projected to the default 400 episodes (target 2 min).

Also times the DESK import of the shared files. ``BENCH_FETCH_EPISODES`` changes the measured size.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from mlnseq import collect
from mlnseq.sources import fetch as fetch_demos

TARGET_SECONDS = 120.0
DESK_SOURCE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "desk-taurus"


def main() -> None:
    episodes = int(os.environ.get("BENCH_FETCH_EPISODES", "100"))
    default_episodes = collect.CollectOptions.episodes

    setup = []  # the first environment also loads MuJoCo and the model once; collect's own is the second
    for _ in range(2):
        started = time.perf_counter()
        fetch_demos.make_env().close()
        setup.append(time.perf_counter() - started)

    started = time.perf_counter()
    collected = fetch_demos.collect(collect.CollectOptions(env="fetch", episodes=episodes, seed=0))
    elapsed = time.perf_counter() - started
    frames = collected.frames.height
    per_episode = max(elapsed - setup[1], 0.0) / episodes
    projected = setup[0] + per_episode * default_episodes
    verdict = "within" if projected <= TARGET_SECONDS else "OVER"
    print(f"fetch collect: {episodes} episodes, {frames:,} frames in {elapsed:.1f} s "
          f"({frames / elapsed:,.0f} frames/s, {per_episode * 1000:.0f} ms/episode, env setup {setup[0]:.2f} s, then {setup[1]:.2f} s)")
    print(f"fetch collect: default {default_episodes} episodes projected {projected:.0f} s, "
          f"{verdict} the {TARGET_SECONDS:.0f} s target ({projected / TARGET_SECONDS:.0%} of it); "
          f"success {collected.meta['success_rate']:.1%}")

    if DESK_SOURCE.is_dir():
        started = time.perf_counter()
        desk = collect.collect(collect.CollectOptions(env="desk", source=DESK_SOURCE)).frames
        elapsed = time.perf_counter() - started
        print(f"desk import: {desk.height:,} frames in {elapsed:.2f} s ({desk.height / elapsed:,.0f} frames/s)")


if __name__ == "__main__":
    main()
