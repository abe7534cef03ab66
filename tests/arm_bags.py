"""ROS 2 bags of a simulated 7-joint arm doing pick and place, one bag per episode, for `mlnseq fit` tests and the
first-day benchmark: /joint_states (7 joints: position, velocity, effort), /gripper/width (std_msgs/Float64, the
fingers' opening in metres) and /phase (std_msgs/String: reach, grasp, transport, place, retreat), written with
rosbags' own writer as tests/desk_bags.py does. 22 channels in all.

The arm follows minimum-jerk moves between joint-space waypoints: from home to the object (on one side of the
base: joint 1 turns towards it), a grasp (the arm still, the gripper closing at the gripper's own speed), a
transport (lift, turn to the place on the other side, the payload loading the shoulder joint 2 and the elbow
joint 4), a place (lower, then the gripper opens) and a retreat home. Efforts are gravity torques of the arm and
the payload plus viscous friction and noise; velocities the positions' derivative plus noise. A ``Robot`` holds
what differs between arms (joint names, rate, masses, speeds, the gripper's range, noise, the side the object
lies on); a seed draws each episode (the object's place and width, the payload, durations, pauses).

Run as a script: ``python tests/arm_bags.py FOLDER [ROBOT] [SEED] [EPISODES]`` writes EPISODES bags (default 6)
into FOLDER and two held-out bags of other seeds into FOLDER-heldout.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

PHASES = ("reach", "grasp", "transport", "place", "retreat")
G = 9.81


@dataclass(frozen=True)
class Robot:
    """What differs between arms; an expert knows all of it from the robot's data sheet and the cell's layout."""

    name: str
    joints: tuple[str, ...]
    rate: float  # Hz, of every topic
    home: tuple[float, ...]  # joint positions, rad
    link_torque: tuple[float, ...]  # gravity torque (N m) of the arm itself on joints 2, 4, 6 at full lever
    lever: float  # m: the payload's lever on joint 2 at full reach
    payload: tuple[float, float]  # kg
    speed: float  # rad/s: a typical joint move's peak speed
    gripper_open: float  # m
    object_width: tuple[float, float]  # m
    gripper_speed: float  # m/s
    side: float = 1.0  # +1: the object lies at positive joint-1 angles and the place at negative ones
    noise: dict[str, float] = field(default_factory=lambda: {"position": 2e-4, "velocity": 0.01, "effort": 0.25,
                                                             "gripper": 2e-5})
    friction: float = 1.5  # N m per rad/s


ROBOTS = {
    "panda": Robot("panda", tuple(f"panda_joint{i}" for i in range(1, 8)), 50.0,
                   (0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8), (6.0, 3.0, 1.0), 0.6, (1.0, 2.0), 0.9,
                   0.08, (0.025, 0.05), 0.05),
    "iiwa": Robot("iiwa", tuple(f"iiwa_joint_{i}" for i in range(1, 8)), 40.0,
                  (0.0, 0.2, 0.0, -1.6, 0.0, 1.1, 0.0), (20.0, 10.0, 2.5), 0.75, (2.0, 4.0), 0.7,
                  0.11, (0.04, 0.07), 0.06, side=-1.0,
                  noise={"position": 3e-4, "velocity": 0.015, "effort": 0.6, "gripper": 5e-5}, friction=4.0),
    "xarm7": Robot("xarm7", tuple(f"joint{i}" for i in range(1, 8)), 60.0,
                   (0.0, -0.5, 0.0, 0.9, 0.0, 1.4, 0.0), (5.0, 2.5, 0.8), 0.5, (0.8, 1.5), 1.1,
                   0.085, (0.02, 0.045), 0.04,
                   noise={"position": 1e-4, "velocity": 0.02, "effort": 0.4, "gripper": 1e-5}, friction=1.0),
}


def at_rate(robot: str, rate: float | None = None) -> Robot:
    """The arm of ROBOTS named ``robot``, its topics at ``rate`` Hz where given (else at its own rate)."""
    return ROBOTS[robot] if rate is None else replace(ROBOTS[robot], rate=rate)


def minimum_jerk(start: np.ndarray, end: np.ndarray, frames: int) -> np.ndarray:
    """[frames, joints] from ``start`` (excluded) to ``end`` (included) along a minimum-jerk profile."""
    s = np.arange(1, frames + 1) / frames
    blend = 10 * s**3 - 15 * s**4 + 6 * s**5
    return start + blend[:, None] * (end - start)


@dataclass
class Episode:
    """One pick and place: joint positions [T, 7], gripper width [T], payload mass held [T], phase index [T]."""

    positions: list[np.ndarray] = field(default_factory=list)
    widths: list[np.ndarray] = field(default_factory=list)
    held: list[np.ndarray] = field(default_factory=list)
    phases: list[np.ndarray] = field(default_factory=list)

    def add(self, positions: np.ndarray, width: np.ndarray | float, held: float, phase: str) -> None:
        n = len(positions)
        self.positions.append(positions)
        self.widths.append(np.broadcast_to(np.asarray(width, dtype=float), (n,)).copy())
        self.held.append(np.full(n, held))
        self.phases.append(np.full(n, PHASES.index(phase)))

    def last(self) -> np.ndarray:
        return self.positions[-1][-1]


def move_frames(robot: Robot, start: np.ndarray, end: np.ndarray, slowness: float) -> int:
    """Frames a move takes: its largest joint change at the robot's speed (min-jerk peaks at 1.875x the mean)."""
    return max(int(round(1.875 * np.abs(end - start).max() / robot.speed * robot.rate * slowness)), 5)


def still(robot: Robot, at: np.ndarray, seconds: float) -> np.ndarray:
    return np.repeat(at[None], max(int(round(seconds * robot.rate)), 1), axis=0)


def trajectory(robot: Robot, rng: np.random.Generator) -> tuple[Episode, float]:
    """The waypoints of one episode and the moves between them; the payload's mass."""
    home = np.array(robot.home) + rng.normal(0, 0.02, 7)
    slowness = rng.uniform(0.8, 1.25)
    side = robot.side
    object_angle, place_angle = side * rng.uniform(0.5, 1.1), -side * rng.uniform(0.5, 1.1)
    reach = rng.uniform(0.35, 0.6)  # how far joint 2 bends forward (and joint 4 unfolds) to reach the table
    grasp = home + np.array([object_angle, reach, rng.normal(0, 0.1), 0.6 * reach, rng.normal(0, 0.1), -0.3 * reach,
                             rng.normal(0, 0.2)])
    lifted = grasp + np.array([0.0, -0.5 * reach, 0.0, -0.3 * reach, 0.0, 0.2 * reach, 0.0])
    carried = lifted.copy()
    carried[0], carried[6] = place_angle, lifted[6] + rng.normal(0, 0.3)
    placed = carried + np.array([0.0, 0.5 * reach, 0.0, 0.3 * reach, 0.0, -0.2 * reach, 0.0]) + rng.normal(0, 0.03, 7)
    width, mass = rng.uniform(*robot.object_width), rng.uniform(*robot.payload)
    opened = robot.gripper_open
    episode = Episode()
    episode.add(still(robot, home, rng.uniform(0.2, 0.6)), opened, 0.0, "reach")
    episode.add(minimum_jerk(home, grasp, move_frames(robot, home, grasp, slowness)), opened, 0.0, "reach")
    closing = max(int(round((opened - width) / robot.gripper_speed * robot.rate)), 3)
    episode.add(still(robot, grasp, rng.uniform(0.2, 0.5)), opened, 0.0, "grasp")
    episode.add(still(robot, grasp, closing / robot.rate), minimum_jerk(np.array([opened]), np.array([width]),
                                                                         closing)[:, 0], 0.0, "grasp")
    episode.add(still(robot, grasp, rng.uniform(0.1, 0.3)), width, 0.0, "grasp")
    for start, end in ((grasp, lifted), (lifted, carried)):
        episode.add(minimum_jerk(start, end, move_frames(robot, start, end, slowness)), width, mass, "transport")
    episode.add(minimum_jerk(carried, placed, move_frames(robot, carried, placed, slowness)), width, mass, "place")
    episode.add(still(robot, placed, rng.uniform(0.1, 0.4)), width, mass, "place")
    episode.add(still(robot, placed, closing / robot.rate), minimum_jerk(np.array([width]), np.array([opened]),
                                                                          closing)[:, 0], 0.0, "place")
    episode.add(minimum_jerk(placed, home, move_frames(robot, placed, home, slowness)), opened, 0.0, "retreat")
    episode.add(still(robot, home, rng.uniform(0.2, 0.5)), opened, 0.0, "retreat")
    return episode, mass


def efforts(robot: Robot, positions: np.ndarray, velocities: np.ndarray, held: np.ndarray) -> np.ndarray:
    """Gravity torques of the arm (joints 2, 4, 6) and of the payload held, plus viscous friction."""
    q2, q4 = positions[:, 1], positions[:, 3]
    reach = np.sin(q2) + 0.5 * np.sin(q2 + q4 + np.pi)  # the horizontal lever of the forearm and the hand
    torque = np.zeros_like(positions)
    arm2, arm4, arm6 = robot.link_torque
    torque[:, 1] = arm2 * np.sin(q2) + arm4 * 0.5 * reach + held * G * robot.lever * (0.6 + 0.4 * np.abs(reach))
    torque[:, 3] = arm4 * np.sin(q2 + q4 + np.pi) * 0.5 + held * G * robot.lever * 0.5
    torque[:, 5] = arm6 * np.sin(positions[:, 5]) + held * G * 0.05
    return torque + robot.friction * velocities


def episode_signals(robot: Robot, seed: int) -> dict[str, np.ndarray]:
    """One episode's channels: positions, velocities, efforts [T, 7], width [T], phase [T] (index into PHASES)."""
    rng = np.random.default_rng(seed)
    episode, _ = trajectory(robot, rng)
    return signals_of(robot, episode, rng)


def signals_of(robot: Robot, episode: Episode, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The channels of ``episode`` as the robot's sensors measure them (noise drawn from ``rng``)."""
    positions = np.concatenate(episode.positions)
    true_velocity = np.gradient(positions, 1 / robot.rate, axis=0)
    held = np.concatenate(episode.held)
    noise = robot.noise
    measured = positions + rng.normal(0, noise["position"], positions.shape)
    velocities = true_velocity + rng.normal(0, noise["velocity"], positions.shape)
    torque = efforts(robot, positions, true_velocity, held) + rng.normal(0, noise["effort"], positions.shape)
    width = np.concatenate(episode.widths) + rng.normal(0, noise["gripper"], len(positions))
    return {"position": measured, "velocity": velocities, "effort": torque, "width": width,
            "phase": np.concatenate(episode.phases)}


def write_bag(path: Path, robot: Robot, seed: int, phases: bool = True,
              signals: dict[str, np.ndarray] | None = None) -> Path:
    """One ROS 2 bag (MCAP storage) of one episode of ``robot`` drawn with ``seed`` (or of ``signals``, as
    ``episode_signals`` makes them); without /phase when not ``phases`` (a recording nobody labelled)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    signals = episode_signals(robot, seed) if signals is None else signals
    store = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header, Time, String, Float64 = (store.types[n] for n in (
        "sensor_msgs/msg/JointState", "std_msgs/msg/Header", "builtin_interfaces/msg/Time", "std_msgs/msg/String",
        "std_msgs/msg/Float64"))
    step, start = int(round(1e9 / robot.rate)), 1_700_000_000 * 10**9 + seed * 10**9
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        gripper = writer.add_connection("/gripper/width", Float64.__msgtype__, typestore=store)
        phase = writer.add_connection("/phase", String.__msgtype__, typestore=store) if phases else None
        previous = None
        for k, label in enumerate(signals["phase"]):
            t = start + k * step
            if label != previous and phase is not None:
                previous = label
                writer.write(phase, t, store.serialize_cdr(String(data=PHASES[label]), String.__msgtype__))
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="base"),
                                 name=list(robot.joints), position=signals["position"][k].copy(),
                                 velocity=signals["velocity"][k].copy(), effort=signals["effort"][k].copy())
            writer.write(joints, t, store.serialize_cdr(message, JointState.__msgtype__))
            writer.write(gripper, t, store.serialize_cdr(Float64(data=float(signals["width"][k])), Float64.__msgtype__))
    return path


def clicks(robot: Robot, seeds: dict[str, int], where: float = 0.5) -> list[str]:
    """One click per phase of each episode (name: seed), at ``where`` of the phase (0: its first frame), as
    ``episode,frame,label`` lines."""
    lines = ["episode,frame,label"]
    for name, seed in seeds.items():
        phase = episode_signals(robot, seed)["phase"]
        for index, label in enumerate(PHASES):
            frames = np.flatnonzero(phase == index)
            lines.append(f"{name},{frames[int(where * (len(frames) - 1))]},{label}")
    return lines


def frames_table(signals: list[dict[str, np.ndarray]], splits: list[str]):
    """frames.parquet of episodes (``episode_signals``' dicts) without writing bags: their 22 channels as features
    x0 .. x21, each episode with its split, the ``unlabelled`` ones without a label."""
    import polars as pl

    from mlnseq.catalog import artifacts

    rows = [np.concatenate([s["position"], s["velocity"], s["effort"], s["width"][:, None]], axis=1)
            for s in signals]
    keys = {"episode": np.concatenate([np.full(len(r), k) for k, r in enumerate(rows)]),
            "frame": np.concatenate([np.arange(len(r)) for r in rows]),
            "label": np.concatenate([s["phase"] for s in signals]),
            "split": np.concatenate([np.full(len(r), str(split)) for r, split in zip(rows, splits)])}
    values = np.concatenate(rows)
    table = artifacts.frames_table(keys, {f"x{c}": values[:, c] for c in range(values.shape[1])})
    return table.with_columns(label=pl.when(pl.col("split") != "unlabelled").then(pl.col("label")))


def write_table(path: Path, robot: str = "xarm7", seed: int = 0, episodes: int = 8, rate: float | None = None) -> Path:
    """``episodes`` episodes of ``robot`` (seeds seed*1000 + 0, 1, ...) as one Parquet table for `collect --env table`:
    episode (ep0, ep1, ...), frame, the 22 channels named by joint (joint1_position ... gripper_width) and label (the
    phase's name); ``rate``: another frame rate than the robot's."""
    import polars as pl

    arm = at_rate(robot, rate)
    tables = []
    for k in range(episodes):
        signals = episode_signals(arm, seed * 1000 + k)
        n = len(signals["phase"])
        columns = {f"joint{j + 1}_{field}": signals[field][:, j] for field in ("position", "velocity", "effort")
                   for j in range(7)}
        tables.append(pl.DataFrame({"episode": [f"ep{k}"] * n, "frame": np.arange(n), **columns,
                                    "gripper_width": signals["width"], "label": np.array(PHASES)[signals["phase"]]}))
    pl.concat(tables).write_parquet(path)
    return path


def write_folders(folder: Path, robot: str = "panda", seed: int = 0, episodes: int = 6, heldout: int = 2,
                  rate: float | None = None) -> tuple[Path, Path]:
    """``episodes`` bags of ``robot`` (seeds seed*1000 + 0, 1, ...) in ``folder`` and ``heldout`` more (the next
    seeds) in FOLDER-heldout; ``rate``: another frame rate than the robot's (more frames per episode)."""
    arm, other = at_rate(robot, rate), folder.with_name(folder.name + "-heldout")
    folder.mkdir(parents=True)
    other.mkdir(parents=True)
    for k in range(episodes + heldout):
        target = folder if k < episodes else other
        write_bag(target / f"episode_{k + 1}", arm, seed * 1000 + k)
    return folder, other


# An honest hand-written spec for these bags, from what the arm's expert knows (ROBOTS above: its data sheet, the
# cell's layout, the gravity model of `efforts`) and not from the recordings: the gripper (open near its full
# opening, closed below the widest object, a dead band a fifth of its motion per frame), the shoulder joint 2's
# effort in two bins (loaded: halfway between the arm alone at the table and the arm lifting the lightest payload)
# and joint 1's change (turning to the object, to the place, or home; a dead band a twentieth of its typical motion
# per frame) and its side (the object's side of the cell or the place's).
def hand_spec(robot: str = "panda", rate: float | None = None) -> str:
    """The hand spec for ``robot``'s bags (at ``rate``, where another than the robot's)."""
    arm = at_rate(robot, rate)
    joint1, joint2 = arm.joints[0], arm.joints[1]
    bent = np.array([0.0, 0.475, 0.0, 0.285, 0.0, -0.1425, 0.0])  # to the table, on average; lifted: half of it
    table, lifted = ((np.array(arm.home) + share * bent)[None] for share in (1.0, 0.5))
    unloaded = efforts(arm, table, np.zeros_like(table), np.zeros(1))[0, 1]
    loaded = efforts(arm, lifted, np.zeros_like(lifted), np.array([arm.payload[0]]))[0, 1]
    return f"""[[predicate]]
name = "gripper"
kind = "gripper"
channel = "/gripper/width/data"
open_above = {arm.gripper_open - 0.005:.4g}
closed_below = {arm.object_width[1] + 0.002:.4g}
threshold = {arm.gripper_speed / arm.rate / 5:.3g}

[[predicate]]
name = "load"
kind = "bins"
channel = "/joint_states/effort/{joint2}"
edges = [{(unloaded + loaded) / 2:.4g}]
values = ["low", "high"]

[[predicate]]
name = "turn"
kind = "change"
channel = "/joint_states/position/{joint1}"
threshold = {arm.speed / arm.rate / 20:.3g}

[[predicate]]
name = "side"
kind = "bins"
channel = "/joint_states/position/{joint1}"
edges = [0.0]
values = {'["place", "object"]' if arm.side > 0 else '["object", "place"]'}
"""


def main(argv: list[str]) -> int:
    """The script: ``FOLDER [ROBOT] [SEED] [EPISODES]``; a usage line (nothing written) for -h, --help or bad
    arguments."""
    usage = f"usage: python tests/arm_bags.py FOLDER [ROBOT: {'|'.join(ROBOTS)}] [SEED] [EPISODES]"
    if not argv or argv[0].startswith("-") or len(argv) > 4:
        print(usage, file=sys.stderr if argv and argv[0] not in ("-h", "--help") else sys.stdout)
        return 0 if argv[:1] in (["-h"], ["--help"]) else 2
    robot = argv[1] if len(argv) > 1 else "panda"
    if robot not in ROBOTS or not all(a.isdigit() for a in argv[2:]):
        print(f"{usage}\nerror: {robot!r} is not a robot here, or SEED and EPISODES are not whole numbers",
              file=sys.stderr)
        return 2
    out = Path(argv[0])
    if out.exists() or out.with_name(out.name + "-heldout").exists():
        print(f"error: {out} or {out}-heldout exists; name a new folder", file=sys.stderr)
        return 2
    write_folders(out, robot, *(int(a) for a in argv[2:4]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
