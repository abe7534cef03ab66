"""Live on ROS: 10 minutes of a 100 Hz /joint_states feed (60,000 messages) through the ROS node's core, and
the same feed as `rostopic echo -p` rows through `mlnseq stream`, as fast as they go.

The model: an lstm (stream mode, 40 epochs) trained on a ROS 1 bag of DESK's arm as /joint_states at 100 Hz
(tests/ros_episode.py, as the ROS tests' model). Side by side in this run:

- node core: each message serialized as ROS 1 sends it, then per message what `mlnseq ros` does on receipt
  (deserialize into sensor_msgs/JointState with rospy's generated class, `MessageFeed.receive`: features by
  joint name, the model's clock, the recogniser); messages per second, the real-time factor (600 s of feed
  / wall time, target > 1), p50 and p99 per message, and resident memory after 10^4 messages and at the end
  (flat: target growth < 10 MB). Needs rospy's message classes (`make setup` links Debian's ROS 1);
  without them the rows below say so;
- stream: `mlnseq stream` fed the 60,000 rows through a pipe; rows per second after start-up;
- real master (where ROS 1 is installed): `rosmaster`, `mlnseq ros` and tests/ros_driver.py publishing 20 s of
  /joint_states at 100 Hz (2,000 messages) and recording /mlnseq/activity/frame: frames answered, and how many
  had arrived when the publisher exited 0.5 s after its last message (all of them when the node keeps up);
- flood, node core: a 1 kHz /joint_states (10x the model's 100 Hz clock: each 100 Hz row sent 10 times) offered to
  `MessageFeed` from a thread as fast as it goes (far faster than the recogniser), the main thread recognising
  what is queued, as `mlnseq ros` does; with the node's bounded queue (1,000) beside an unbounded one: messages
  dropped, frames answered, resident memory growth while the flood lasts (target < 10 MB with the bound);
- flood, real master: the node fed 10 s of that 1 kHz feed through `rosmaster`: frames, messages dropped, and the
  node process's resident memory at the start and the end of the flood.

The machine's load average is printed first: these machines are shared, and a preempted process shows in p99.

``BENCH_QUICK=1`` feeds 6,000 messages (1 minute) instead.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))  # the ROS tests' episode writer: one definition of the messages
SHARED = REPO.parent / "shared" / "data"
MESSAGES = 6_000 if os.environ.get("BENCH_QUICK") else 60_000
TARGET_RT, TARGET_GROWTH_MB = 1.0, 10.0


def resident_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def node_core(model_path: Path, rows: np.ndarray) -> None:
    import ros_episode
    from mlnseq.recognition.live import MessageFeed
    from mlnseq.recognition.recognizer import Recognizer

    try:
        import rospy
        from sensor_msgs.msg import JointState
    except ImportError as error:
        print(f"node core: skipped, rospy's message classes are not importable ({error})")
        return
    feed = MessageFeed(Recognizer.load(model_path), print, time.monotonic)
    wire = []
    for k in range(MESSAGES):  # the live rows, replayed: 100 Hz stamps throughout
        t = ros_episode.START + k * ros_episode.STEP
        message = JointState(name=ros_episode.JOINTS, position=rows[k % len(rows), :7].tolist())
        message.header.stamp = rospy.Time(t // 10**9, t % 10**9)
        buffer = io.BytesIO()
        message.serialize(buffer)
        wire.append(buffer.getvalue())
    costs = np.empty(len(wire))  # held from the start: the benchmark's own list would grow the memory it measures
    frames, memory, checkpoint = 0, float("nan"), min(10_000, len(wire) // 6)
    started = time.perf_counter()
    for k, data in enumerate(wire):
        begin = time.perf_counter()
        frames += len(feed.receive("/joint_states", JointState().deserialize(data), 0))
        costs[k] = time.perf_counter() - begin
        if k + 1 == checkpoint:
            memory = resident_mb()
    wall = time.perf_counter() - started
    frames += len(feed.finish())
    growth = resident_mb() - memory
    feed_s = MESSAGES * ros_episode.STEP / 1e9
    p50, p99 = 1e3 * np.percentile(costs, [50, 99])
    print(f"node core: {MESSAGES:,} messages ({feed_s:,.0f} s of a 100 Hz feed) -> {frames:,} frames in {wall:.2f} s: "
          f"{MESSAGES / wall:,.0f} messages/s, {feed_s / wall:,.0f}x real time (target > {TARGET_RT:g}x)")
    print(f"node core: per message p50 {p50:.3f} ms, p99 {p99:.3f} ms (a 100 Hz feed leaves 10 ms)")
    print(f"node core: resident memory {memory:.1f} MB after {checkpoint:,} messages, {growth:+.1f} MB by the end "
          f"(target < {TARGET_GROWTH_MB:g} MB)")


def flood(model_path: Path, rows: np.ndarray) -> None:
    import threading

    import ros_episode
    from mlnseq.recognition.live import QUEUE, MessageFeed
    from mlnseq.recognition.recognizer import Recognizer

    try:
        from sensor_msgs.msg import JointState
    except ImportError as error:
        print(f"flood, node core: skipped, rospy's message classes are not importable ({error})")
        return
    import rospy

    wire = []
    for k in range(MESSAGES):  # 1 kHz stamps, each 100 Hz row 10 times
        t = ros_episode.START + k * ros_episode.STEP // 10
        message = JointState(name=ros_episode.JOINTS, position=rows[(k // 10) % len(rows), :7].tolist())
        message.header.stamp = rospy.Time(t // 10**9, t % 10**9)
        buffer = io.BytesIO()
        message.serialize(buffer)
        wire.append(buffer.getvalue())
    for bound in (QUEUE, 10**9):
        feed = MessageFeed(Recognizer.load(model_path), lambda _: None, time.monotonic, queue_size=bound,
                           decode=lambda topic, data: JointState().deserialize(data))
        # each message a new buffer, as a client library hands over (a copy of the bytes)
        producer = threading.Thread(target=lambda: [feed.offer("/joint_states", bytes(bytearray(data)), 0)
                                                    for data in wire])
        start, peak, frames = resident_mb(), 0.0, 0
        began = time.perf_counter()
        producer.start()
        while producer.is_alive() or feed.queue:
            frames += len(feed.pending(0.01))
            peak = max(peak, resident_mb())
        frames += len(feed.drain())
        wall = time.perf_counter() - began
        name = f"bounded queue of {bound:,}" if bound == QUEUE else "unbounded queue"
        print(f"flood, node core, {name}: {MESSAGES:,} messages of a 1 kHz feed offered in {wall:.2f} s -> "
              f"{frames:,} frames, {feed.dropped:,} messages dropped; resident memory {peak - start:+.1f} MB at "
              f"its peak (target < {TARGET_GROWTH_MB:g} MB with the bound)")


def stream_pipe(model_path: Path, rows: np.ndarray, folder: Path) -> None:
    import ros_episode

    lines = ros_episode.echo_csv(np.concatenate([rows] * (MESSAGES // len(rows) + 1))[:MESSAGES])
    feed = folder / "echo.csv"
    feed.write_text("\n".join(lines) + "\n")
    mlnseq = str(Path(sys.executable).parent / "mlnseq")
    begin = time.perf_counter()
    subprocess.run([mlnseq, "stream", str(model_path)], input=(lines[0] + "\n").encode(), capture_output=True,
                   check=True)
    startup = time.perf_counter() - begin
    begin = time.perf_counter()
    with open(feed, "rb") as source:
        done = subprocess.run([mlnseq, "stream", str(model_path)], stdin=source, capture_output=True, check=True)
    wall = time.perf_counter() - begin
    answered = done.stdout.count(b"\n")
    print(f"stream: `rostopic echo -p` rows -> {answered:,} frames in {wall:.2f} s ({startup:.2f} s start-up): "
          f"{MESSAGES / max(wall - startup, 1e-9):,.0f} rows/s after start-up")


def real_master(model_path: Path, rows: np.ndarray, folder: Path, hz: float = 100.0, count: int = 2_000) -> None:
    import shutil
    import signal
    import socket

    what = "real master" if hz == 100 else "flood, real master"
    if shutil.which("rosmaster") is None:
        print(f"{what}: skipped, rosmaster is not installed (`make setup` as root on Debian installs it)")
        return
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "ROS_MASTER_URI": f"http://127.0.0.1:{port}", "ROS_IP": "127.0.0.1",
           "ROS_HOME": str(folder / "ros"), "PYTHONUNBUFFERED": "1",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO / "tests"), os.environ.get("PYTHONPATH")]))}
    repeat = round(hz / 100)  # each 100 Hz row sent this many times
    np.save(folder / "rows.npy", np.repeat(np.concatenate([rows] * (count // len(rows) // repeat + 1)), repeat,
                                           axis=0)[:count])
    record, started, node_log = folder / "node.jsonl", [], folder / "node.log"
    record.unlink(missing_ok=True)
    driver = [sys.executable, str(REPO / "tests" / "ros_driver.py")]

    def start(args, **kwargs):
        started.append(subprocess.Popen(args, env=env, start_new_session=True, **{"stderr": subprocess.DEVNULL,
                                                                                   **kwargs}))
        return started[-1]

    try:
        start(["rosmaster", "--core", "-p", str(port)], stdout=subprocess.DEVNULL)
        time.sleep(1.5)
        with open(node_log, "w") as log:
            node = start([str(Path(sys.executable).parent / "mlnseq"), "ros", str(model_path)], stdout=log,
                         stderr=log)
        recorder = start([*driver, "record", "/mlnseq/activity/frame", str(record)], stdout=subprocess.PIPE, text=True)
        if recorder.stdout.readline().strip() != "ready":
            print(f"{what}: the recorder found no node")
            return
        before = process_mb(node.pid)
        publisher = start([*driver, "publish", str(folder / "rows.npy"), "1", str(hz)], stdout=subprocess.DEVNULL)
        publisher.wait(120)
        after = process_mb(node.pid)
        at_exit = len(record.read_text().splitlines())  # the driver exits 0.5 s after its last message
        deadline = time.monotonic() + 30
        while len(record.read_text().splitlines()) < count // repeat - 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        answered = len(record.read_text().splitlines())
        node.send_signal(signal.SIGTERM)
        node.wait(30)
    finally:
        for process in reversed(started):
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
    stopped = node_log.read_text().strip().splitlines()[-1]
    print(f"{what}: {count:,} messages at {hz:g} Hz ({count / hz:.0f} s) -> {answered:,} frames answered (the last tick "
          f"waits for a later message), {at_exit:,} of them already when the publisher exited 0.5 s after its last "
          f"message; the node's resident memory {before:.1f} MB -> {after:.1f} MB; {stopped}")


def process_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main() -> None:
    print(f"load average: {' '.join(Path('/proc/loadavg').read_text().split()[:3])} on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        import ros_episode

        model, rows, _ = ros_episode.trained_model(folder, SHARED)

        live = rows[ros_episode.TRAIN_FRAMES:]
        node_core(model, live)
        flood(model, live)
        stream_pipe(model, live, folder)
        real_master(model, live, folder)
        real_master(model, live, folder, hz=1000.0, count=1_000 if os.environ.get("BENCH_QUICK") else 10_000)


if __name__ == "__main__":
    main()
