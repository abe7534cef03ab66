"""Hostile and unusual recordings, written with each format's own library: each is read right or refused in
one line, never read silently wrong. Values come from the real DESK kinematics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="the [recordings] extra is not installed")

from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from mlnseq import sources  # noqa: E402
from mlnseq.catalog.errors import BadInput  # noqa: E402
from mlnseq.sources import SourceOptions  # noqa: E402
from mlnseq.sources.recording import Labels, TableColumns  # noqa: E402

STORE = get_typestore(Stores.ROS2_HUMBLE)
JointState, Header, Time = (STORE.types[n] for n in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                     "builtin_interfaces/msg/Time"))
START, STEP = 1_700_000_000 * 10**9, 20_000_000  # 50 Hz


@pytest.fixture(scope="module")
def desk(shared_data) -> np.ndarray:
    return np.loadtxt(shared_data / "desk-taurus" / "taurus_kinematics_train.txt")[:600]


def joint_state(t: int, names: list[str], position) -> object:
    stamp = Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="base")
    return JointState(header=stamp, name=names, position=np.asarray(position, dtype=np.float64),
                      velocity=np.zeros(0), effort=np.zeros(0))


def write_bag(path: Path, messages) -> Path:
    """A ROS 2 MCAP bag of (time ns, JointState) on /joint_states."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=STORE)
        for t, message in messages:
            writer.write(joints, t, STORE.serialize_cdr(message, JointState.__msgtype__))
    return path


def read_bag(path: Path):
    (recording,) = sources.read("rosbag", path, TableColumns(), SourceOptions(topics=("/joint_states",), rate=50.0),
                                label=Labels.NONE)
    return recording


def test_joint_states_are_read_by_name_when_a_publisher_reorders_them(desk, tmp_path):
    """Joints a, b, c; after 300 messages the same publisher lists them as c, a, b: each value stays its joint's."""
    order = ["a", "b", "c"]
    values = {name: desk[:, k] for k, name in enumerate(order)}
    messages = []
    for k in range(600):
        names = order if k < 300 else ["c", "a", "b"]
        messages.append((START + k * STEP, joint_state(START + k * STEP, names, [values[n][k] for n in names])))
    recording = read_bag(write_bag(tmp_path / "reordered", messages))
    assert recording.features.columns == [f"/joint_states/position/{n}" for n in order]
    for name in order:
        np.testing.assert_array_equal(recording.features[f"/joint_states/position/{name}"].to_numpy(), values[name])


def test_an_arm_and_a_gripper_publishing_on_joint_states_merge_by_name_on_the_causal_clock(desk, tmp_path):
    """7 arm joints at 50 Hz and 2 finger joints at 10 Hz, starting 3 ticks later, on one topic: 9 features,
    the clock starting once every joint has a value, each tick holding each joint's last value."""
    arm, fingers = [f"panda_joint{i}" for i in range(1, 8)], ["finger_left", "finger_right"]
    messages = []
    for k in range(600):
        t = START + k * STEP
        messages.append((t, joint_state(t, arm, desk[k, :7])))
        if k >= 3 and k % 5 == 3:
            messages.append((t, joint_state(t, fingers, desk[k, 12:14])))
    recording = read_bag(write_bag(tmp_path / "arm_and_gripper", messages))
    names = recording.features.columns
    assert names == [f"/joint_states/position/{j}" for j in (*arm, *fingers)]
    ticks = np.arange(3, 600)  # the clock starts at the fingers' first message
    assert recording.features.height == len(ticks)
    np.testing.assert_array_equal(recording.features.select(names[:7]).to_numpy(), desk[ticks, :7])
    last_finger = 3 + ((ticks - 3) // 5) * 5
    np.testing.assert_array_equal(recording.features.select(names[7:]).to_numpy(), desk[last_finger, 12:14])


def test_a_joint_state_whose_values_do_not_match_its_names_is_refused(desk, tmp_path):
    messages = [(START + k * STEP, joint_state(START + k * STEP, ["a", "b", "c"], desk[k, :3 if k < 10 else 2]))
                for k in range(20)]
    with pytest.raises(BadInput, match=r"reordered.*'/joint_states'.*position holds 2 values for 3 joint names"):
        read_bag(write_bag(tmp_path / "reordered", messages))


def arm_and_gripper(desk: np.ndarray, gripper_from: int, velocity: bool = True) -> list:
    """An arm publisher (7 joints with velocities) every tick and a gripper publisher (2 fingers, positions only)
    every 5th tick from ``gripper_from`` (0: its first message before the arm's)."""
    arm, fingers = [f"panda_joint{i}" for i in range(1, 8)], ["finger_left", "finger_right"]
    messages = []
    for k in range(300):
        t = START + k * STEP
        if k >= gripper_from and k % 5 == gripper_from % 5:
            messages.append((t, joint_state(t, fingers, desk[k, 12:14])))
        message = joint_state(t, arm, desk[k, :7])
        if velocity:
            message = JointState(header=message.header, name=arm, position=message.position,
                                 velocity=np.asarray(desk[k, 7:14], dtype=np.float64), effort=np.zeros(0))
        messages.append((t, message))
    return messages


def test_a_folder_of_bags_gets_one_column_order_whichever_publisher_comes_first(desk, tmp_path):
    """Bag 1: the gripper's first message before the arm's; bag 2: after the clock started. Both give bag 1's
    columns, positions (fingers, arm: as first seen) then velocities, so collect reads the folder as one table."""
    folder = tmp_path / "bags"
    folder.mkdir()
    write_bag(folder / "1_gripper_first", arm_and_gripper(desk, 0))
    write_bag(folder / "2_gripper_later", arm_and_gripper(desk, 4))
    recordings = sources.read("rosbag", folder, TableColumns(), SourceOptions(topics=("/joint_states",), rate=50.0),
                              label=Labels.NONE)
    arm, fingers = [f"panda_joint{i}" for i in range(1, 8)], ["finger_left", "finger_right"]
    expected = ([f"/joint_states/position/{j}" for j in (*fingers, *arm)]
                + [f"/joint_states/velocity/{j}" for j in arm])
    assert [r.features.columns for r in recordings] == [expected, expected]
    assert [r.features.height for r in recordings] == [300, 296]
    np.testing.assert_array_equal(recordings[1].features.select(expected[9:]).to_numpy(), desk[4:300, 7:14])
