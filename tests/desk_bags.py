"""A user's folder of ROS 2 bags made from the real DESK Taurus kinematics: one bag per trial (a trial starts
where the surgeme returns to S1), /joint_states of both arms (x, y, z, three angles, gripper opening, as
`left_x` ... `right_gripper`) at 50 Hz and a /phase std_msgs/String topic of the surgeme's name. Written with
rosbags' own writer, as tests/stages/sources/test_rosbag.py does.

Run as a script to write them: ``python tests/desk_bags.py FOLDER`` (the first 6 trials into FOLDER, the
7th and the partial 8th into FOLDER-heldout).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

STEP, START = 20_000_000, 1_700_000_000 * 10**9  # 50 Hz
JOINTS = [f"{arm}_{name}" for arm in ("left", "right") for name in ("x", "y", "z", "roll", "pitch", "yaw", "gripper")]

# The paper's DESK predicates written by hand for these bags (stages/specs/desk.binarize.toml's rules on the raw
# channels: gripper opening in percent, the arms' distance from their positions), as the README names them.
HAND_SPEC = (Path(__file__).resolve().parents[1] / "examples" / "desk-bags.binarize.toml").read_text()


def trials(desk: np.ndarray) -> list[np.ndarray]:
    """The DESK training file cut where the surgeme returns to S1 (label 0) from another."""
    labels = desk[:, -1].astype(int)
    starts = [0] + [i for i in range(1, len(labels)) if labels[i] == 0 and labels[i - 1] != 0]
    return [desk[a:b] for a, b in zip(starts, starts[1:] + [len(desk)])]


def write_bag(path: Path, trial: np.ndarray, every: int = 1) -> Path:
    """One ROS 2 bag (MCAP storage) of a trial's frames (each ``every``-th), with its /phase."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from mlnseq.sources.desk import CLASSES

    store = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header, Time, String = (store.types[n] for n in (
        "sensor_msgs/msg/JointState", "std_msgs/msg/Header", "builtin_interfaces/msg/Time", "std_msgs/msg/String"))
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        phase = writer.add_connection("/phase", String.__msgtype__, typestore=store)
        previous = None
        for k, row in enumerate(trial[::every]):
            t = START + k * STEP
            if row[-1] != previous:
                previous = row[-1]
                writer.write(phase, t, store.serialize_cdr(String(data=CLASSES[int(previous)]), String.__msgtype__))
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="base"),
                                 name=JOINTS, position=row[:14].copy(), velocity=np.zeros(0), effort=np.zeros(0))
            writer.write(joints, t, store.serialize_cdr(message, JointState.__msgtype__))
    return path


def write_folders(desk: np.ndarray, folder: Path, heldout: Path, every: int = 1) -> tuple[Path, Path]:
    """The first 6 trials as bags in ``folder``, the rest as one bag in ``heldout`` (a folder of one bag)."""
    cut = trials(desk)
    folder.mkdir(parents=True)
    heldout.mkdir(parents=True)
    for k, trial in enumerate(cut[:6], start=1):
        write_bag(folder / f"trial_{k}", trial, every)
    write_bag(heldout / "trial_7", np.concatenate(cut[6:]), every)
    return folder, heldout


def main(argv: list[str]) -> int:
    """Write FOLDER and FOLDER-heldout; both there already as this script writes them: said, and nothing done; a
    folder in the way: one line, exit 2 (never a folder removed)."""
    if len(argv) != 2:
        print("usage: python tests/desk_bags.py FOLDER", file=sys.stderr)
        return 2
    out = Path(argv[1])
    heldout = out.with_name(out.name + "-heldout")
    expected = {out: [f"trial_{k}" for k in range(1, 7)], heldout: ["trial_7"]}
    if all(folder.is_dir() and sorted(p.name for p in folder.iterdir()) == names for folder, names in expected.items()):
        print(f"{out} and {heldout} are there already: nothing to do (remove them to write them again)")
        return 0
    for folder in expected:
        if folder.exists():
            print(f"error: {folder} exists and is not the bags this script writes: remove it or name another folder",
                  file=sys.stderr)
            return 2
    data = Path(__file__).resolve().parents[2] / "shared" / "data" / "desk-taurus" / "taurus_kinematics_train.txt"
    write_folders(np.loadtxt(data), out, heldout)
    print(f"wrote {out} (trial_1 .. trial_6) and {heldout} (trial_7)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
