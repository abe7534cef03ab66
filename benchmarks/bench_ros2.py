"""Live on ROS 2 over DDS: 10^5 /joint_states messages (1,000 s of a 100 Hz feed) through the ROS 2 node, in its
core and between real DDS processes.

The model: the ROS tests' lstm (tests/ros_episode.py's ``trained_model``). Side by side in this run:

- node core: each message as its CDR bytes (rosbags' writer, a ROS 2 bag's bytes), then what `mlnseq ros --ros 2`
  does on receipt: the DDS type built from the typestore deserializes it, `MessageFeed.receive` puts it on the
  clock and recognises; messages per second, the real-time factor (feed seconds / wall time, target > 1), p50 and
  p99 per message, resident memory after 10^4 messages and at the end (flat: growth < 10 MB);
- real DDS: `mlnseq ros --ros 2` in its own process, fed by tests/dds_driver.py publishing a ROS 2 bag of the same
  messages at 20x their pace (2 kHz, stamps 10 ms apart) over the loopback (a localhost-only configuration, a
  discovery tag of its own), the activity frames recorded by another driver: frames answered of those published,
  frames per second, the node's CPU time per 1,000 messages and its resident memory after 10^4 frames and at the
  end.

The machine's load average is printed first: these machines are shared, and a preempted process shows in p99.
``BENCH_QUICK=1`` sends 10^4 messages instead.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.bench_ros import REPO, SHARED, TARGET_GROWTH_MB, TARGET_RT, resident_mb

MESSAGES = 10_000 if os.environ.get("BENCH_QUICK") else 100_000
SPEED = 20.0  # the real-DDS run sends the 100 Hz feed 20x faster: 2 kHz
CHECKPOINT = 10_000 if MESSAGES > 10_000 else 2_000


def feed_rows(live: np.ndarray) -> np.ndarray:
    return np.concatenate([live] * (MESSAGES // len(live) + 1))[:MESSAGES]


def node_core(model_path: Path, rows: np.ndarray, bag: Path) -> None:
    from rosbags.highlevel import AnyReader

    from mlnseq.dds.types import MessageTypes
    from mlnseq.recognition.live import MessageFeed
    from mlnseq.recognition.recognizer import Recognizer

    with AnyReader([bag]) as reader:
        wire = [bytes(raw) for c, _, raw in reader.messages([c for c in reader.connections if c.topic != "/phase"])]
    JointState = MessageTypes("humble").get("sensor_msgs/msg/JointState")
    feed = MessageFeed(Recognizer.load(model_path), print, time.monotonic)
    costs = np.empty(len(wire))
    frames, memory = 0, float("nan")
    started = time.perf_counter()
    for k, data in enumerate(wire):
        begin = time.perf_counter()
        frames += len(feed.receive("/joint_states", JointState.deserialize(data), 0))
        costs[k] = time.perf_counter() - begin
        if k + 1 == CHECKPOINT:
            memory = resident_mb()
    wall = time.perf_counter() - started
    frames += len(feed.finish())
    growth = resident_mb() - memory
    feed_s = len(wire) / 100
    p50, p99 = 1e3 * np.percentile(costs, [50, 99])
    print(f"node core: {len(wire):,} messages ({feed_s:,.0f} s of a 100 Hz feed) -> {frames:,} frames in {wall:.2f} s: "
          f"{len(wire) / wall:,.0f} messages/s, {feed_s / wall:,.0f}x real time (target > {TARGET_RT:g}x)")
    print(f"node core: per message p50 {p50:.3f} ms, p99 {p99:.3f} ms (a 100 Hz feed leaves 10 ms)")
    print(f"node core: resident memory {memory:.1f} MB after {CHECKPOINT:,} messages, {growth:+.1f} MB by the end "
          f"(target < {TARGET_GROWTH_MB:g} MB)")


def process_status(pid: int) -> tuple[float, float]:
    """A process's resident memory (MB) and CPU time (s)."""
    rss = next(int(line.split()[1]) / 1024 for line in Path(f"/proc/{pid}/status").read_text().splitlines()
               if line.startswith("VmRSS:"))
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return rss, (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def real_dds(model_path: Path, bag: Path, folder: Path) -> None:
    config = folder / "cyclonedds.xml"
    config.write_text('<CycloneDDS><Domain><General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
                      '<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto'
                      '</ParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers>'
                      f'<Tag>mlnseq-bench-{os.getpid()}</Tag></Discovery></Domain></CycloneDDS>')
    env = {**{k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "CYCLONEDDS"))},
           "ROS_DOMAIN_ID": str(random.randrange(1, 200)), "CYCLONEDDS_URI": config.as_uri(),
           "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO / "tests"), os.environ.get("PYTHONPATH")]))}
    driver, record, started = [sys.executable, str(REPO / "tests" / "dds_driver.py")], folder / "frames.jsonl", []

    def start(args, **kwargs):
        started.append(subprocess.Popen(args, env=env, start_new_session=True, stderr=subprocess.DEVNULL, **kwargs))
        return started[-1]

    def answered() -> int:
        return record.read_bytes().count(b"\n") if record.exists() else 0

    try:
        node = start([str(Path(sys.executable).parent / "mlnseq"), "ros", str(model_path), "--ros", "2"])
        recorder = start([*driver, "record", "/mlnseq/activity/frame", str(record)], stdout=subprocess.PIPE, text=True)
        if recorder.stdout.readline().strip() != "ready":
            print("real DDS: the recorder found no node")
            return
        publisher = start([*driver, "publish", str(bag), "1", str(SPEED)], stdout=subprocess.DEVNULL)
        while answered() < CHECKPOINT and publisher.poll() is None:
            time.sleep(0.01)
        begin, first = time.perf_counter(), answered()
        memory, cpu = process_status(node.pid)
        publisher.wait(MESSAGES / 100 / SPEED * 4 + 60)
        deadline = time.monotonic() + 30
        while answered() < MESSAGES - 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        wall, last = time.perf_counter() - begin, answered()
        end_memory, end_cpu = process_status(node.pid)
        node.send_signal(signal.SIGINT)
        node.wait(30)
    finally:
        for process in reversed(started):
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
    print(f"real DDS: {MESSAGES:,} messages at {100 * SPEED:,.0f} Hz -> {answered():,} frames answered "
          f"({(last - first) / wall:,.0f} frames/s after the first {first:,}); the node's CPU "
          f"{1000 * (end_cpu - cpu) / max(last - first, 1):.2f} s per 1,000 messages")
    print(f"real DDS: the node's resident memory {memory:.1f} MB after {first:,} frames, {end_memory - memory:+.1f} MB "
          f"by the end (target < {TARGET_GROWTH_MB:g} MB)")


def main() -> None:
    sys.path.insert(0, str(REPO / "tests"))
    import ros2_episode
    import ros_episode

    print(f"load average: {' '.join(Path('/proc/loadavg').read_text().split()[:3])} on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        model, rows, _ = ros_episode.trained_model(folder, SHARED)
        bag = ros2_episode.write_bag(folder / "feed", feed_rows(rows[ros_episode.TRAIN_FRAMES:]))
        node_core(model, rows, bag)
        real_dds(model, bag, folder)


if __name__ == "__main__":
    main()
