"""Failed demonstrations of the generated arm of tests/arm_bags.py, for `mlnseq audit`'s tests and benchmark: a clean
episode drawn as arm_bags draws it (its Robot, waypoints and minimum-jerk moves), then changed where a real
demonstration goes wrong. Each kind names the phase where it goes wrong (``Failure.wrong``):

- ``drop``: the object slips out of the fingers mid-transport (the load gone, the fingers close on nothing); the
  arm carries on and opens its empty gripper at the place.
- ``miss``: the grasp closes on nothing (the fingers shut); the arm transports and places nothing.
- ``pause``: the arm stops for 3 to 6 s mid-transport, holding the object, then goes on.
- ``regrasp``: the first grasp closes on nothing; the gripper opens, the arm shifts and grasps again, then goes on.
- ``abort``: after lifting the object the arm lowers it back where it was, lets go and goes home (never placed).
- ``open``: the gripper never closes: transport and place with open fingers and no load.
- ``repeat``: after letting go at the place, the arm grasps the object again, lifts it and places it a second time.
- ``reach``: the arm turns back home halfway to the object, without grasping (a reach abandoned).
- ``slip``: the object slips out as the arm lowers it to the place (the load gone, the fingers shut on nothing).
- ``bump``: the arm hits something mid-transport: it stops, backs off a little, then carries on.
- ``early``: the fingers open before the arm is at the place, dropping the object from the carry's end.
- ``hold``: the fingers never open at the place: the arm goes home still holding the object.
- ``fumble``: the fingers close on the object, open halfway and close again before the lift.
- ``drag``: the object is never lifted: the arm drags it along the table to the place and lets go there.

And two clean ones that are slower than any labelled recording (``slow``: every move 1.5 to 1.8 times slower;
``hesitant``: a stop of 0.4 to 1 s before each move), which a curator keeps. The labels are the phases a person
would mark (the /phase topic): a repeated grasp is grasp again, an aborted transport ends in a place.

Run as a script: ``python tests/arm_failures.py FOLDER [ROBOT] [SEED] [PER_KIND]`` writes PER_KIND bags of each failed
kind and as many clean ones (default 1; seeds SEED*1000+500 on, after arm_bags' own) into FOLDER, without /phase,
named KIND_SEED.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import arm_bags  # noqa: E402
from arm_bags import ROBOTS, Episode, Robot, minimum_jerk, still  # noqa: E402

FAILED = ("drop", "miss", "pause", "regrasp", "abort", "open", "repeat", "reach", "slip", "bump", "early", "hold",
          "fumble", "drag")
CLEAN = ("clean", "slow", "hesitant")
EMPTY = 0.002  # m: the fingers' opening closed on nothing
# The segments arm_bags.trajectory adds, in order.
HOME, REACH, BEFORE, CLOSE, HELD, LIFT, CARRY, LOWER, SETTLE, OPEN, RETREAT, REST = range(12)


@dataclass(frozen=True)
class Failure:
    """One recording's channels (as arm_bags.episode_signals makes them), its kind, where it went wrong and its
    frame rate."""

    kind: str
    seed: int
    signals: dict
    wrong: str | None  # the phase where it went wrong; None: a clean recording
    rate: float  # Hz, the arm's it was drawn for

    @property
    def failed(self) -> bool:
        return self.wrong is not None


@dataclass
class Part:
    positions: np.ndarray
    width: np.ndarray
    held: np.ndarray
    phase: str


def parts_of(episode: Episode) -> list[Part]:
    return [Part(p, w, h, arm_bags.PHASES[int(k[0])]) for p, w, h, k in
            zip(episode.positions, episode.widths, episode.held, episode.phases)]


def episode_of(parts: list[Part]) -> Episode:
    episode = Episode()
    for part in parts:
        episode.add(part.positions, part.width, float(part.held[0]) if part.held.size else 0.0, part.phase)
        episode.held[-1] = np.broadcast_to(part.held, (len(part.positions),)).copy()
    return episode


def gripper(robot: Robot, start: float, end: float) -> np.ndarray:
    """The gripper's opening moving from ``start`` to ``end`` at its own speed (at least 3 frames)."""
    frames = max(int(round(abs(start - end) / robot.gripper_speed * robot.rate)), 3)
    return minimum_jerk(np.array([start]), np.array([end]), frames)[:, 0]


def hold(at: np.ndarray, frames: int) -> np.ndarray:
    return np.repeat(at[None], frames, axis=0)


def moving_gripper(positions: np.ndarray, widths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions and widths of a move during which the gripper moves too: the shorter one held at its end."""
    n = max(len(positions), len(widths))
    positions = np.concatenate([positions, hold(positions[-1], n - len(positions))])
    widths = np.concatenate([widths, np.full(n - len(widths), widths[-1])])
    return positions, widths


def split(part: Part, at: float) -> tuple[Part, Part]:
    k = min(max(int(round(at * len(part.positions))), 1), len(part.positions) - 1)
    return (Part(part.positions[:k], part.width[:k], part.held[:k], part.phase),
            Part(part.positions[k:], part.width[k:], part.held[k:], part.phase))


def emptied(parts: list[Part], robot: Robot) -> list[Part]:
    """Parts whose gripper holds nothing: no load, the fingers closed on nothing; their last opening from there."""
    out = []
    for part in parts:
        width = np.full(len(part.positions), EMPTY)
        if part is parts[-1] and part.width[-1] > part.width[0]:  # the opening at the place
            width = gripper(robot, EMPTY, robot.gripper_open)
            positions, width = moving_gripper(part.positions, width)
            out.append(Part(positions, width, np.zeros(len(width)), part.phase))
            continue
        out.append(Part(part.positions, width, np.zeros(len(width)), part.phase))
    return out


def let_go(robot: Robot, parts: list[Part], during: int, at: float, empty_from: int, phase: str
           ) -> tuple[list[Part], str]:
    """The object lost at ``at`` of part ``during`` (of the phase ``phase``, where the recording goes wrong): the
    fingers close on nothing from there, and the parts from ``empty_from`` to the opening carry nothing."""
    before, after = split(parts[during], at)
    width = parts[HELD].width[-1]
    positions, closing = moving_gripper(after.positions, gripper(robot, width, EMPTY))
    slipping = Part(positions, closing, np.zeros(len(positions)), phase)
    return parts[:during] + [before, slipping] + emptied(parts[empty_from:OPEN + 1], robot) + parts[RETREAT:], phase


def drop(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    return let_go(robot, parts, CARRY, rng.uniform(0.25, 0.75), LOWER, "transport")


def miss(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    closing = gripper(robot, robot.gripper_open, EMPTY)
    shut = Part(hold(parts[CLOSE].positions[0], len(closing)), closing, np.zeros(len(closing)), "grasp")
    return (parts[:CLOSE] + [shut] + emptied(parts[HELD:OPEN + 1], robot) + parts[RETREAT:]), "grasp"


def pause(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    before, after = split(parts[CARRY], rng.uniform(0.2, 0.8))
    frames = int(round(rng.uniform(3.0, 6.0) * robot.rate))
    stopped = Part(hold(before.positions[-1], frames), np.full(frames, before.width[-1]),
                   np.full(frames, before.held[-1]), "transport")
    return parts[:CARRY] + [before, stopped, after] + parts[LOWER:], "transport"


def regrasp(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    at = parts[CLOSE].positions[0]
    shut = gripper(robot, robot.gripper_open, EMPTY)
    reopen = gripper(robot, EMPTY, robot.gripper_open)
    shifted = at + rng.normal(0, 0.04, 7) * np.array([1, 1, 0, 1, 0, 0, 1])
    away = arm_bags.move_frames(robot, at, shifted, 1.0) + 10
    tries = [Part(hold(at, len(shut)), shut, np.zeros(len(shut)), "grasp"),
             Part(hold(at, len(reopen)), reopen, np.zeros(len(reopen)), "grasp")]
    for start, end in ((at, shifted), (shifted, at)):
        tries.append(Part(minimum_jerk(start, end, away), np.full(away, robot.gripper_open), np.zeros(away), "grasp"))
    return parts[:CLOSE] + tries + parts[CLOSE:], "grasp"


def abort(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    lift = parts[LIFT]
    lifted, grasped = lift.positions[-1], lift.positions[0]
    frames = len(lift.positions)
    width = parts[HELD].width[-1]
    back = Part(minimum_jerk(lifted, grasped, frames), np.full(frames, width), lift.held.copy(), "place")
    opening = gripper(robot, width, robot.gripper_open)
    let_go = Part(hold(grasped, len(opening)), opening, np.zeros(len(opening)), "place")
    home = parts[RETREAT].positions[-1]
    n = len(parts[RETREAT].positions)
    going = Part(minimum_jerk(grasped, home, n), np.full(n, robot.gripper_open), np.zeros(n), "retreat")
    return parts[:CARRY] + [back, let_go, going, parts[REST]], "transport"


def opened(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    out = parts[:CLOSE]
    for part in parts[CLOSE:OPEN + 1]:
        n = len(part.positions)
        out.append(Part(part.positions, np.full(n, robot.gripper_open), np.zeros(n), part.phase))
    return out + parts[RETREAT:], "grasp"


def repeat(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    placed = parts[OPEN].positions[-1]
    width = parts[HELD].width[-1]
    mass = float(parts[LIFT].held[0])
    closing = gripper(robot, robot.gripper_open, width)
    lifted = placed + np.array([0.0, -0.15, 0.0, -0.1, 0.0, 0.05, 0.0])
    up = arm_bags.move_frames(robot, placed, lifted, 1.0)
    again = [Part(hold(placed, len(closing)), closing, np.zeros(len(closing)), "grasp"),
             Part(minimum_jerk(placed, lifted, up), np.full(up, width), np.full(up, mass), "transport"),
             Part(minimum_jerk(lifted, placed, up), np.full(up, width), np.full(up, mass), "place")]
    opening = gripper(robot, width, robot.gripper_open)
    again.append(Part(hold(placed, len(opening)), opening, np.zeros(len(opening)), "place"))
    return parts[:RETREAT] + again + parts[RETREAT:], "place"


def reach(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    before, _ = split(parts[REACH], rng.uniform(0.4, 0.7))
    turned = before.positions[-1]
    home = parts[HOME].positions[0]
    n = len(before.positions)
    back = Part(minimum_jerk(turned, home, n), np.full(n, robot.gripper_open), np.zeros(n), "retreat")
    return [parts[HOME], before, back, parts[REST]], "reach"


def slip(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    return let_go(robot, parts, LOWER, rng.uniform(0.2, 0.6), SETTLE, "place")


def bump(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    before, after = split(parts[CARRY], rng.uniform(0.3, 0.7))
    at, width, held = before.positions[-1], before.width[-1], before.held[-1]
    back = at - (at - before.positions[0]) * rng.uniform(0.1, 0.25)
    frames = arm_bags.move_frames(robot, at, back, 0.5)
    stopped = int(round(rng.uniform(0.5, 1.0) * robot.rate))
    recoil = [Part(hold(at, stopped), np.full(stopped, width), np.full(stopped, held), "transport"),
              Part(minimum_jerk(at, back, frames), np.full(frames, width), np.full(frames, held), "transport"),
              Part(minimum_jerk(back, at, 2 * frames), np.full(2 * frames, width), np.full(2 * frames, held),
                   "transport")]
    return parts[:CARRY] + [before] + recoil + [after] + parts[LOWER:], "transport"


def early(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    before, after = split(parts[CARRY], rng.uniform(0.6, 0.85))
    width = parts[HELD].width[-1]
    positions, opening = moving_gripper(after.positions, gripper(robot, width, robot.gripper_open))
    let_go = Part(positions, opening, np.zeros(len(positions)), "transport")
    rest = []
    for part in parts[LOWER:OPEN + 1]:
        n = len(part.positions)
        rest.append(Part(part.positions, np.full(n, robot.gripper_open), np.zeros(n), part.phase))
    return parts[:CARRY] + [before, let_go] + rest + parts[RETREAT:], "transport"


def hold_on(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    width, mass = parts[HELD].width[-1], float(parts[LIFT].held[0])
    out = parts[:OPEN]
    for part in parts[OPEN:]:
        n = len(part.positions)
        out.append(Part(part.positions, np.full(n, width), np.full(n, mass), part.phase))
    return out, "place"


def fumble(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    at, width = parts[CLOSE].positions[-1], parts[HELD].width[-1]
    halfway = width + (robot.gripper_open - width) * rng.uniform(0.4, 0.6)
    again = []
    for start, end in ((width, halfway), (halfway, width)):
        moving = gripper(robot, start, end)
        again.append(Part(hold(at, len(moving)), moving, np.zeros(len(moving)), "grasp"))
    return parts[:HELD] + again + parts[HELD:], "grasp"


def drag(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], str]:
    grasped, lifted = parts[LIFT].positions[0], parts[LIFT].positions[-1]
    end = parts[CARRY].positions[-1] - (lifted - grasped)  # the carry's end at the table's height
    carry, mass = parts[CARRY], float(parts[LIFT].held[0])
    n = len(carry.positions)
    dragged = Part(minimum_jerk(grasped, end, n), carry.width, np.full(n, mass), "transport")
    out = parts[:LIFT] + [dragged]
    for part in parts[LOWER:OPEN + 1]:  # set down where it was dragged to: no lowering
        out.append(Part(hold(end, len(part.positions)), part.width, part.held, part.phase))
    home = parts[RETREAT].positions[-1]
    m = len(parts[RETREAT].positions)
    out.append(Part(minimum_jerk(end, home, m), parts[RETREAT].width, parts[RETREAT].held, "retreat"))
    return out + parts[REST:], "transport"


def slow(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], None]:
    factor = rng.uniform(1.5, 1.8)
    out = []
    for part in parts:
        n = len(part.positions)
        m = max(int(round(n * factor)), 1)
        s = np.linspace(0, n - 1, m)
        positions = np.stack([np.interp(s, np.arange(n), part.positions[:, j]) for j in range(7)], axis=1)
        out.append(Part(positions, np.interp(s, np.arange(n), part.width), np.interp(s, np.arange(n), part.held),
                        part.phase))
    return out, None


def hesitant(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], None]:
    out = []
    for index, part in enumerate(parts):
        if index in (REACH, LIFT, CARRY, LOWER, RETREAT):
            frames = int(round(rng.uniform(0.4, 1.0) * robot.rate))
            out.append(Part(hold(part.positions[0], frames), np.full(frames, part.width[0]),
                            np.full(frames, part.held[0]), part.phase))
        out.append(part)
    return out, None


def clean(robot: Robot, parts: list[Part], rng: np.random.Generator) -> tuple[list[Part], None]:
    return parts, None


KINDS = {"drop": drop, "miss": miss, "pause": pause, "regrasp": regrasp, "abort": abort, "open": opened,
         "repeat": repeat, "reach": reach, "clean": clean, "slow": slow, "hesitant": hesitant, "slip": slip,
         "bump": bump, "early": early, "hold": hold_on, "fumble": fumble, "drag": drag}


def failure(robot: Robot, kind: str, seed: int) -> Failure:
    """One recording of ``kind`` drawn with ``seed``: the clean episode arm_bags draws with that seed, then changed
    (a ``clean`` one is arm_bags' own, channel for channel)."""
    rng = np.random.default_rng(seed)
    episode, _ = arm_bags.trajectory(robot, rng)
    if kind == "clean":
        return Failure(kind, seed, arm_bags.signals_of(robot, episode, rng), None, robot.rate)
    changed, wrong = KINDS[kind](robot, parts_of(episode), np.random.default_rng([seed, FAILED_SEED[kind]]))
    return Failure(kind, seed, arm_bags.signals_of(robot, episode_of(changed), rng), wrong, robot.rate)


FAILED_SEED = {kind: k + 1 for k, kind in enumerate(KINDS)}


def failures(robot: str, kinds: tuple[str, ...], seeds: range | list[int], rate: float | None = None) -> list[Failure]:
    """Every kind at every seed, for ``robot`` (a name of arm_bags.ROBOTS; ``rate``: another frame rate than its)."""
    arm = arm_bags.at_rate(robot, rate)
    return [failure(arm, kind, seed) for kind in kinds for seed in seeds]


def frames_columns(robot: str) -> list[str]:
    """The feature names `collect --env rosbag` gives these bags' channels, in arm_bags.frames_table's order."""
    joints = ROBOTS[robot].joints
    return ([f"/joint_states/{field}/{joint}" for field in ("position", "velocity", "effort") for joint in joints]
            + ["/gripper/width/data"])


def table(recordings: list[Failure], robot: str, names: list[str] | None = None):
    """The recordings as one table an audit reads with --env table: an ``episode`` column (KIND_SEED, or ``names``),
    a ``time`` column in seconds (at each recording's rate) and the bags' feature names."""
    import polars as pl

    columns = frames_columns(robot)
    parts = []
    for k, recording in enumerate(recordings):
        s = recording.signals
        values = np.concatenate([s["position"], s["velocity"], s["effort"], s["width"][:, None]], axis=1)
        name = names[k] if names else f"{recording.kind}_{recording.seed}"
        frame = pl.DataFrame({c: values[:, i] for i, c in enumerate(columns)})
        parts.append(frame.with_columns(pl.lit(name).alias("episode"),
                                        (pl.int_range(pl.len()) / recording.rate).alias("time")))
    return pl.concat(parts).select("episode", "time", *columns)


def write_bags(folder: Path, robot: str, kinds: tuple[str, ...], seeds: list[int]) -> list[Failure]:
    """Each recording as a ROS 2 bag KIND_SEED in ``folder`` (no /phase: a recording to audit)."""
    folder.mkdir(parents=True, exist_ok=True)
    made = failures(robot, kinds, seeds)
    for recording in made:
        arm_bags.write_bag(folder / f"{recording.kind}_{recording.seed}", ROBOTS[robot], recording.seed, phases=False,
                           signals=recording.signals)
    return made


if __name__ == "__main__":
    out = Path(sys.argv[1])
    arm = sys.argv[2] if len(sys.argv) > 2 else "panda"
    first = int(sys.argv[3]) if len(sys.argv) > 3 else 0
    per_kind = int(sys.argv[4]) if len(sys.argv) > 4 else 1
    write_bags(out, arm, ("clean", *FAILED), [first * 1000 + 500 + k for k in range(per_kind)])
