"""DESK's Taurus arm as ROS messages: its 7 joint positions as sensor_msgs/JointState at 100 Hz (header stamp =
the bag's record time) and its phase as std_msgs/String, written as ROS 1 bags with rosbags, and as the CSV
`rostopic echo -p /joint_states` prints; shared by the ROS tests, their fixture and the ROS benchmark."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mlnseq.sources.desk import CLASSES  # DESK's seven phases, by index

JOINTS = [f"panda_joint{i}" for i in range(1, 8)]
START, STEP = 1_700_000_000 * 10**9, 10_000_000  # ns: 100 Hz
TRAIN_FRAMES = 1000  # of the 1,405 frames of taurus_kinematics_train.txt: the model's bag; the rest is live


def desk_rows(shared_data: Path) -> np.ndarray:
    """The DESK kinematics: 7 joint columns first, the phase index last."""
    return np.loadtxt(shared_data / "desk-taurus" / "taurus_kinematics_train.txt")


def write_bag(path: Path, rows: np.ndarray, start: int = START) -> Path:
    """/joint_states every 10 ms and /phase where the phase changes, as a ROS 1 bag."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    JointState, Header, Time = (types[n] for n in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                   "builtin_interfaces/msg/Time"))
    String = types["std_msgs/msg/String"]
    with Writer(path) as writer:
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        phase = writer.add_connection("/phase", String.__msgtype__, typestore=store)
        previous = None
        for k, row in enumerate(rows):
            t = start + k * STEP
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="base"),
                                 name=JOINTS, position=row[:7].copy(), velocity=np.zeros(0), effort=np.zeros(0))
            writer.write(joints, t, store.serialize_ros1(message, JointState.__msgtype__))
            if row[-1] != previous:
                previous = row[-1]
                writer.write(phase, t, store.serialize_ros1(String(data=CLASSES[int(previous)]), String.__msgtype__))
    return path


def trained_model(folder: Path, shared_data: Path) -> tuple[Path, np.ndarray, Path]:
    """An lstm (stream mode, 40 epochs) trained on a bag of the first TRAIN_FRAMES rows in ``folder`` and exported:
    (the model file, every row, the workdir)."""
    from mlnseq import collect, export, train
    from mlnseq.sources import SourceOptions

    rows = desk_rows(shared_data)
    bag = write_bag(folder / "train.bag", rows[:TRAIN_FRAMES])
    workdir = folder / "work"
    collect.run(workdir, collect.CollectOptions(env="rosbag", source=bag, recordings=SourceOptions(
        topics=("/joint_states",), label_topic="/phase")))
    train.run(workdir, train.TrainOptions(method="lstm", mode="stream", epochs=40))
    model = export.run(workdir, export.ExportOptions(method="lstm", output=folder / "lstm.mlnseq")).path
    return model, rows, workdir


def echo_csv(rows: np.ndarray, repeat: int = 1, start: int = START) -> list[str]:
    """The lines `rostopic echo -p /joint_states` prints for these messages, each sent ``repeat`` times evenly
    within its 10 ms (a 100·repeat Hz feed holding the 100 Hz signal); joints listed in reverse from row 7 on."""
    names = ",".join(f"field.name{i}" for i in range(7))
    lines = [f"%time,field.header.seq,field.header.stamp,field.header.frame_id,{names},"
             + ",".join(f"field.position{i}" for i in range(7))]
    seq = 0
    for k, row in enumerate(rows):
        order = list(range(7)) if k < 7 else list(range(6, -1, -1))
        for j in range(repeat):
            t = start + k * STEP + j * STEP // repeat
            seq += 1
            lines.append(f"{t},{seq},{t},base," + ",".join(JOINTS[i] for i in order) + ","
                         + ",".join(repr(float(row[i])) for i in order))
    return lines
