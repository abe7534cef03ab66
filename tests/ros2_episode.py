"""DESK's Taurus arm as ROS 2 bags (rosbags' writer, CDR): /joint_states (sensor_msgs/JointState, stamped with the
record time, tests/ros_episode.py's 100 Hz clock) and /phase (std_msgs/String); with ``gripper``, the arm's
gripper opening leaves the JointState for a topic of its own, /gripper (std_msgs/Float64, no header: its time is
when it was sent) at half the rate. Shared by the ROS 2 tests and the ROS 2 benchmark."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ros_episode import JOINTS, START, STEP
from mlnseq.sources.desk import CLASSES

GRIPPER_EVERY = 2  # /gripper: every other frame, 50 Hz


def write_bag(path: Path, rows: np.ndarray, gripper: bool = False, start: int = START) -> Path:
    """A ROS 2 bag (sqlite3 storage) of the rows: the joints every 10 ms, the phase where it changes."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header, Time, String, Float64 = (store.types[n] for n in (
        "sensor_msgs/msg/JointState", "std_msgs/msg/Header", "builtin_interfaces/msg/Time", "std_msgs/msg/String",
        "std_msgs/msg/Float64"))
    joints = JOINTS[:6] if gripper else JOINTS
    with Writer(path, version=8) as writer:
        states = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        held = writer.add_connection("/gripper", Float64.__msgtype__, typestore=store) if gripper else None
        phase = writer.add_connection("/phase", String.__msgtype__, typestore=store)
        previous = None
        for k, row in enumerate(rows):
            t = start + k * STEP
            if row[-1] != previous:
                previous = row[-1]
                writer.write(phase, t, store.serialize_cdr(String(data=CLASSES[int(previous)]), String.__msgtype__))
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="base"),
                                 name=joints, position=row[:len(joints)].copy(), velocity=np.zeros(0),
                                 effort=np.zeros(0))
            writer.write(states, t, store.serialize_cdr(message, JointState.__msgtype__))
            if held is not None and k % GRIPPER_EVERY == 0:
                writer.write(held, t + 1, store.serialize_cdr(Float64(data=float(row[6])), Float64.__msgtype__))
    return path
