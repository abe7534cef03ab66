"""Reading a ROS 2 bag: collect's rosbag reader beside rosbags' own read-and-deserialise loop over the same
messages (target: within 1.5x; each timed twice, alternated, in a fresh process, imports left out, the
faster kept), and peak memory of both on a 10-minute and a 1-hour bag (it must not grow
with the messages: they are streamed; the frames made grow, and are printed beside).

The bags are generated here (MCAP storage, rosbags' writer): ``/joint_states`` at 100 Hz, 7 joints.
``BENCH_BAG_MINUTES`` changes the long bag's length (default 60: 360,000 messages).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_RATIO = 1.5
RATE = 100
JOINTS = 7

READ = r"""
import json, resource, sys, time
from pathlib import Path
path, how = Path(sys.argv[1]), sys.argv[2]
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from mlnseq import sources
from mlnseq.sources import SourceOptions, rosbag
from mlnseq.sources.recording import Labels, TableColumns
started = time.perf_counter()  # imports left out of both
if how == "collect":
    recording = sources.read("rosbag", path, TableColumns(), SourceOptions(topics=("/joint_states",)), label=Labels.NONE)[0]
    frames, size = recording.features.height, recording.features.estimated_size()
else:
    frames, size = 0, 0
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        connections = [c for c in reader.connections if c.topic == "/joint_states"]
        for connection, timestamp, raw in reader.messages(connections=connections):
            reader.deserialize(raw, connection.msgtype)
            frames += 1
elapsed = time.perf_counter() - started
print(json.dumps({"seconds": elapsed, "frames": frames, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "frames_mb": size / 2**20}))
"""


def write_bag(path: Path, minutes: float) -> int:
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header, Time = (store.types[n] for n in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                         "builtin_interfaces/msg/Time"))
    names = [f"joint{i + 1}" for i in range(JOINTS)]
    n = int(minutes * 60 * RATE)
    start = 1_700_000_000 * 10**9
    phases = np.linspace(0, 1, JOINTS)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        for k in range(n):
            t = start + k * 10**9 // RATE
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id=""), name=names,
                                 position=np.sin(k / RATE + phases), velocity=np.cos(k / RATE + phases),
                                 effort=np.zeros(0))
            writer.write(connection, t, store.serialize_cdr(message, JointState.__msgtype__))
    return n


def measure(path: Path, how: str) -> dict:
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-c", READ, str(path), how], capture_output=True, text=True, cwd=root,
                          env={**os.environ, "PYTHONPATH": str(root)}, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    minutes = float(os.environ.get("BENCH_BAG_MINUTES", "60"))
    with tempfile.TemporaryDirectory() as folder:
        results = {}
        for label, length in (("10-minute", 10.0), (f"{minutes:g}-minute", minutes)):
            path = Path(folder) / f"bag-{length:g}"
            started = time.perf_counter()
            messages = write_bag(path, length)
            written = time.perf_counter() - started
            runs = [(measure(path, "rosbags"), measure(path, "collect")) for _ in range(2)]  # alternated; the faster kept
            rosbags_loop = min((r[0] for r in runs), key=lambda r: r["seconds"])
            ours = min((r[1] for r in runs), key=lambda r: r["seconds"])
            results[label] = (messages, rosbags_loop, ours)
            ratio = ours["seconds"] / rosbags_loop["seconds"]
            verdict = "within" if ratio <= TARGET_RATIO else "OVER"
            print(f"{label} bag, {messages:,} messages (written in {written:.1f} s): rosbags read+deserialise "
                  f"{rosbags_loop['seconds']:.2f} s, collect's reader {ours['seconds']:.2f} s "
                  f"({ours['frames']:,} frames of {JOINTS * 2} features): {ratio:.2f}x, {verdict} the "
                  f"{TARGET_RATIO}x target")
        (short_n, short_loop, short), (long_n, long_loop, long) = results.values()
        print(f"peak memory: collect's reader {short['peak_mb']:.0f} MB -> {long['peak_mb']:.0f} MB for "
              f"{long_n / short_n:.0f}x the messages (both import the same modules first; the frames it returns: {short['frames_mb']:.0f} -> "
              f"{long['frames_mb']:.0f} MB); rosbags' loop {short_loop['peak_mb']:.0f} -> {long_loop['peak_mb']:.0f} MB")


if __name__ == "__main__":
    main()
