"""Stale and late channels of a bag said, and held at most --max-hold: a /joint_states publisher whose joints change
mid-bag (another driver takes over), a joint that appears later, and a topic that goes silent, each read by collect
and by predict (as the model remembers its reading): one note per topic and time naming the joints and the times,
the frames past the hold dropped."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="the [recordings] extra is not installed")

from rosbags.rosbag1 import Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

import ros_episode  # noqa: E402
from mlnseq import predict, sources  # noqa: E402
from mlnseq.catalog.errors import BadInput  # noqa: E402
from mlnseq.sources import SourceOptions  # noqa: E402
from mlnseq.sources.recording import Labels, TableColumns  # noqa: E402
from mlnseq.sources.table import collect_frames  # noqa: E402
from mlnseq.recognition.reading import ReadOptions  # noqa: E402

STORE = get_typestore(Stores.ROS2_HUMBLE)
JointState, Header, Time, String, Float64 = (STORE.types[f"{n}"] for n in (
    "sensor_msgs/msg/JointState", "std_msgs/msg/Header", "builtin_interfaces/msg/Time", "std_msgs/msg/String",
    "std_msgs/msg/Float64"))
START, STEP = ros_episode.START, ros_episode.STEP  # 100 Hz


def write(path: Path, joints_at, frames: int = 1000, gripper_silent: tuple[float, float] | None = None) -> Path:
    """/joint_states every 10 ms naming ``joints_at(k)`` (position = sin), /phase every 2 s, and with
    ``gripper_silent`` a 20 Hz /gripper (Float64) silent between those seconds."""
    with Writer(path) as writer:
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=STORE)
        phase = writer.add_connection("/phase", String.__msgtype__, typestore=STORE)
        gripper = writer.add_connection("/gripper", Float64.__msgtype__, typestore=STORE) if gripper_silent else None
        for k in range(frames):
            t = START + k * STEP
            if k % 200 == 0:
                writer.write(phase, t, STORE.serialize_ros1(String(data="ab"[k // 200 % 2]), String.__msgtype__))
            names = joints_at(k)
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id=""), name=names,
                                 position=np.sin(np.arange(len(names)) + k / 50), velocity=np.zeros(0),
                                 effort=np.zeros(0))
            writer.write(joints, t, STORE.serialize_ros1(message, JointState.__msgtype__))
            if gripper and k % 5 == 0 and not gripper_silent[0] <= k / 100 < gripper_silent[1]:
                writer.write(gripper, t, STORE.serialize_ros1(Float64(data=k / 100), Float64.__msgtype__))
    return path


def read(path: Path, **options):
    recording = sources.read("rosbag", path, TableColumns(), SourceOptions(label_topic="/phase", **options))[0]
    return recording, recording.resolved["notes"]


def handover(k: int) -> list[str]:
    return ["a", "b", "c"] if k < 300 else ["x", "y", "z"]


def test_joints_that_stop_when_another_driver_takes_over_are_held_max_hold_then_dropped(tmp_path):
    bag = write(tmp_path / "handover.bag", handover)
    recording, notes = read(bag)  # the default hold: 2 s
    times = recording.time.to_numpy()
    assert times[0] == 3.0 and abs(times[-1] - 4.99) < 1e-9 and len(times) == 200  # x, y, z from 3 s; a, b, c to 4.99
    assert notes == [
        "handover.bag: /joint_states position/a, position/b, position/c stop at 2.99 s, before the end at 9.99 s: "
        "held 2 s (--max-hold), then missing: 500 frames dropped",
        "handover.bag: /joint_states position/x, position/y, position/z start at 3.00 s, after the recording's first "
        "message at 0.00 s: missing until then, so the frames start at 3.00 s, once every channel has a value"]
    held, notes = read(bag, max_hold=float("inf"))
    assert held.features.height == 700 and (held.features["/joint_states/position/a"][-400:] ==
                                            held.features["/joint_states/position/a"][-1]).all()
    assert notes[0] == ("handover.bag: /joint_states position/a, position/b, position/c stop at 2.99 s, before the "
                        "end at 9.99 s: held to the end (--max-hold inf)")
    _, meta = collect_frames([recording])
    assert meta["features"][:3] == [f"/joint_states/position/{j}" for j in "abc"]


def test_a_joint_that_appears_later_is_missing_until_it_comes_and_said(tmp_path):
    bag = write(tmp_path / "late.bag", lambda k: ["x", "y", "z"] + (["d"] if k >= 600 else []))
    recording, notes = read(bag)
    assert recording.time[0] == 6.0 and recording.features.height == 400
    assert notes == ["late.bag: /joint_states position/d starts at 6.00 s, after the recording's first message at "
                     "0.00 s: missing until then, so the frames start at 6.00 s, once every channel has a value"]
    with pytest.raises(BadInput, match=r"late-handover.bag: no frame has a value of every feature within --max-hold 2 s "
                       r"\(/joint_states position/a, position/b, position/c stop at 2.99 s.*: read fewer --topics"):
        read(write(tmp_path / "late-handover.bag", lambda k: handover(k) + (["d"] if k >= 600 else [])))


def test_a_topic_silent_past_the_hold_drops_those_frames_and_the_bag_goes_on(tmp_path):
    bag = write(tmp_path / "silent.bag", lambda k: ["a", "b"], gripper_silent=(4.0, 7.5))
    recording, notes = read(bag, topics=("/joint_states", "/gripper"))
    times = recording.time.to_numpy()
    gap = (times > 5.95 + 1e-9) & (times < 7.5 - 1e-9)
    assert not gap.any() and recording.features.height == 1000 - 154  # 5.96 .. 7.49 s dropped
    assert notes == ["silent.bag: /gripper data sends nothing from 3.95 s to 7.50 s: held 2 s (--max-hold), then "
                     "missing: 154 frames dropped"]
    held, notes = read(bag, topics=("/joint_states", "/gripper"), max_hold=4)
    assert held.features.height == 1000 and notes == []


def test_predict_reads_a_new_bag_with_the_models_hold_and_says_the_stale_joints(joint_state_model, tmp_path):
    """The DESK arm's live rows as a bag whose joints 5-7 stop at 1.5 s (another driver publishes 1-4 only)."""
    rows = joint_state_model["live"]  # 405 rows: 4.05 s
    names = ros_episode.JOINTS
    with Writer(tmp_path / "arm.bag") as writer:
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=STORE)
        for k, row in enumerate(rows):
            t, n = START + k * STEP, 7 if k < 150 else 4
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id=""),
                                 name=names[:n], position=row[:n].copy(), velocity=np.zeros(0), effort=np.zeros(0))
            writer.write(joints, t, STORE.serialize_ros1(message, JointState.__msgtype__))
    result = predict.run(predict.PredictOptions(model=joint_state_model["model"], source=tmp_path / "arm.bag",
                                                output=tmp_path / "p.parquet"))
    assert result.table.height == 350 and result.table["time"][-1] == pytest.approx(3.49)
    assert result.notes == ("arm.bag: /joint_states position/panda_joint5, position/panda_joint6, position/panda_joint7 "
                            "stop at 1.49 s, before the end at 4.04 s: held 2 s (--max-hold), then missing: 55 frames "
                            "dropped",)
    assert result.reading["max_hold"] == 2.0
    held = predict.run(predict.PredictOptions(model=joint_state_model["model"], source=tmp_path / "arm.bag",
                                              output=tmp_path / "q.parquet",
                                              reading=ReadOptions(overrides={"max_hold": float("inf")})))
    assert held.table.height == 405 and "held to the end" in held.notes[0]
    assert held.table.head(350)["class"].equals(result.table["class"])


def test_a_topic_slower_than_the_hold_is_one_line_for_all_its_gaps(tmp_path):
    with Writer(tmp_path / "slower.bag") as writer:  # a topic sending every 0.5 s, with a hold of 0.2 s
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=STORE)
        slow = writer.add_connection("/slow", Float64.__msgtype__, typestore=STORE)
        for k in range(300):
            t = START + k * STEP
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id=""),
                                 name=["a"], position=np.array([k / 100]), velocity=np.zeros(0), effort=np.zeros(0))
            writer.write(joints, t, STORE.serialize_ros1(message, JointState.__msgtype__))
            if k % 50 == 0:
                writer.write(slow, t, STORE.serialize_ros1(Float64(data=k / 100), Float64.__msgtype__))
    recording = sources.read("rosbag", tmp_path / "slower.bag", TableColumns(), SourceOptions(max_hold=0.2),
                             label=Labels.NONE)[0]
    notes = recording.resolved["notes"]
    assert notes == ["slower.bag: /slow data sends nothing for over 0.2 s 5 times between 0.00 s and 2.50 s: each time "
                     "held 0.2 s (--max-hold), then missing: 145 frames dropped (a topic this slow needs a longer "
                     "--max-hold)", "slower.bag: /slow data stops at 2.50 s, before the end at 2.99 s: held 0.2 s "
                     "(--max-hold), then missing: 29 frames dropped"]
    assert recording.features.height == 300 - 145 - 29


def test_a_topic_sent_once_is_a_latched_value_held_throughout(tmp_path):
    with Writer(tmp_path / "latched.bag") as writer:  # /calibration sent once, at the start (as /tf_static is)
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=STORE)
        once = writer.add_connection("/calibration", Float64.__msgtype__, typestore=STORE)
        writer.write(once, START, STORE.serialize_ros1(Float64(data=0.5), Float64.__msgtype__))
        for k in range(500):
            t = START + k * STEP
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id=""),
                                 name=["a"], position=np.array([k / 100]), velocity=np.zeros(0), effort=np.zeros(0))
            writer.write(joints, t, STORE.serialize_ros1(message, JointState.__msgtype__))
    recording = sources.read("rosbag", tmp_path / "latched.bag", TableColumns(), SourceOptions(rate=100),
                             label=Labels.NONE)[0]
    assert recording.features.height == 500 and (recording.features["/calibration/data"] == 0.5).all()
    assert recording.resolved["notes"] == ["latched.bag: /calibration data sent one message, at 0.00 s (a latched "
                                           "value): held to the end, whatever --max-hold"]
