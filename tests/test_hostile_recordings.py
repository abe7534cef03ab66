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
