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
  CPU seconds;
- live, the ROS nodes' core: a model trained on a ROS bag of DESK's arm (/joint_states at 100 Hz, the ROS tests' rows:
  tests/ros_episode.py; its suggested predicates, formulas and weights, an lstm of 5 stream-mode epochs, exported as
  lstm+smooth@5), fed LIVE_MESSAGES sensor_msgs/JointState messages as the ROS 2 node receives them (Cyclone DDS
  types, `MessageFeed.receive`: the model's clock, the recogniser, the frame's JSON as published on TOPIC/frame),
  with and without ``--explain 3`` (``explain_steps(3)``): CPU time per frame, best of 3 passes each; and the same
  messages as `rostopic echo -p` rows through ``mlnseq stream`` and ``stream --explain 3``, CPU time per frame less
  start-up (what `mlnseq echo | mlnseq stream` and the ROS 1 node cost). Needs cyclonedds and rosbags (the extra
  ros2); without them the lines say so.

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

import numpy as np
import polars as pl

from benchmarks.bench_recognize import combined_model
from mlnseq.recognition.recognizer import Recognizer

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))  # the ROS tests' episode writer: one definition of the messages
FEATURES = ("arm_distance", "left_gripper", "right_gripper")
TARGET_US = 50.0
ROUNDS = 5
LIVE_MESSAGES = 6_000  # 60 s of a 100 Hz feed (BENCH_QUICK: 1,500)


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
        live_costs(Path(folder), 1_500 if rounds == 1 else LIVE_MESSAGES)


def live_model(folder: Path) -> tuple[Path, object]:
    """An lstm+smooth@5 trained on a ROS bag of DESK's arm, as the ROS tests' lagged model; and the DESK rows."""
    import ros_episode
    from mlnseq import binarize, collect, conflate, export, formulas, learn_weights, train
    from mlnseq.sources import SourceOptions

    rows = ros_episode.desk_rows(REPO.parent / "shared" / "data")
    bag = ros_episode.write_bag(folder / "train.bag", rows[:ros_episode.TRAIN_FRAMES])
    workdir = folder / "ros-work"
    collect.run(workdir, collect.CollectOptions(env="rosbag", source=bag, recordings=SourceOptions(
        topics=("/joint_states",), label_topic="/phase")))
    train.run(workdir, train.TrainOptions(method="lstm", mode="stream", epochs=5))
    binarize.run(workdir, binarize.BinarizeOptions(suggest=workdir / "suggested.binarize.toml"))
    formulas.run(workdir, formulas.FormulasOptions())
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions())
    conflate.run(workdir, conflate.ConflateOptions(decode=("smooth",), lags=(5,)))
    return export.run(workdir, export.ExportOptions(method="lstm", decode="smooth", lag=5,
                                                    output=folder / "lstm-smooth.mlnseq")).path, rows


def live_costs(folder: Path, messages: int) -> None:
    """The ROS 2 node's core and `stream` on echo rows, with and without explanations: CPU us a frame."""
    try:
        from mlnseq.dds.types import MessageTypes
        import cyclonedds  # noqa: F401
    except ImportError as error:
        print(f"live: skipped, the extra ros2 is not installed ({error})", flush=True)
        return
    import ros_episode
    from mlnseq.recognition.live import MessageFeed

    model, rows = live_model(folder)
    live = rows[ros_episode.TRAIN_FRAMES:]
    types = MessageTypes("humble")
    JointState, Header, Time = (types.get(name) for name in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                             "builtin_interfaces/msg/Time"))
    stamps = [ros_episode.START + k * ros_episode.STEP for k in range(messages)]
    wire = [JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="base"),
                       name=ros_episode.JOINTS, position=live[k % len(live), :7].tolist(), velocity=[], effort=[])
            for k, t in enumerate(stamps)]
    best = {}
    for _ in range(3):
        for count in (0, 3):
            recognizer = Recognizer.load(model)
            if count:
                recognizer.explain_steps(count)
            feed, frames = MessageFeed(recognizer, lambda _: None, time.monotonic), 0
            started = time.process_time()
            for message in wire:
                for frame in feed.receive("/joint_states", message, 0):
                    frame.json(recognizer.classes)
                    frames += 1
            per_frame = (time.process_time() - started) / max(frames, 1) * 1e6
            best[count] = min(best.get(count, float("inf")), per_frame)
    print(f"live, ROS 2 node core, lstm+smooth@5 from a bag, {messages:,} JointState messages: {best[0]:.1f} us a "
          f"frame, {best[3]:.1f} us with --explain 3 ({best[3] - best[0]:+.1f} us)", flush=True)
    mlnseq = str(Path(sys.executable).parent / "mlnseq")
    lines = ros_episode.echo_csv(np.asarray([live[k % len(live)] for k in range(messages)]))
    text, header = "\n".join(lines) + "\n", lines[0] + "\n"
    costs = {}
    for flags in ((), ("--explain", "3")):
        command = [mlnseq, "stream", str(model), *flags]
        costs[flags] = (timed(command, text) - timed(command, header)) / messages * 1e6
    plain, explained = costs[()], costs[("--explain", "3")]
    print(f"live, stream on `rostopic echo -p` rows, lstm+smooth@5, {messages:,} rows: {plain:.1f} us a frame, "
          f"{explained:.1f} us with --explain 3 ({explained - plain:+.1f} us)", flush=True)


if __name__ == "__main__":
    main()
