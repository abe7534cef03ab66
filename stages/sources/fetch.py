"""Scripted pick-and-place demonstrations in MuJoCo (FetchPickAndPlace-v4), labelled by controller phase.

The controller is the one of openai/baselines' HER data generation (``goToGoal`` in
``fetch_data_generation.py``): each step it moves by a fixed gain times the position error, first to 3 cm
above the block with the gripper opening (reach), then down onto it while closing (grasp), then to the
goal (transport), then it holds still with the gripper closed to the end of the episode (place). A phase
ends when its error falls below a threshold and never comes back. Gaussian noise on the commanded motion
makes episodes with the same layout differ; object and goal come from the environment's own seeded reset.

Simulated episodes can be kept in a cache folder (``collect --cache DIR``), one file per collection keyed
by everything that decides the episodes: their count and seed, the controller's settings, this module's
source and the simulator's versions. `make reproduce` simulates Fetch once and builds every Fetch
dataset (paper split, goals, data-efficiency splits) from the same cached episodes.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

import numpy as np

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.sources.recording import Collected, split_by_position

ENV_ID = "FetchPickAndPlace-v4"
EPISODE_STEPS = 50  # the environment's time limit
RATE_HZ = 25.0  # steps per second: each step is 0.04 s of simulated time
DEFAULT_TRAIN_FRAMES = 126  # the paper's Fetch training set: its first 126 frames

CLASSES = ("reach", "grasp", "transport", "place")
REACH, GRASP, TRANSPORT, PLACE = range(len(CLASSES))

# The 25 observation values in the order of gymnasium-robotics' BaseFetchEnv._get_obs. Velocities are
# displacements per step; object_velp is relative to the gripper's; gripper_state holds the two finger
# positions (right finger joint first, as in the model's joint order).
OBSERVATION_FEATURES = tuple(
    [f"grip_pos_{a}" for a in "xyz"]
    + [f"object_pos_{a}" for a in "xyz"]
    + [f"object_rel_pos_{a}" for a in "xyz"]
    + ["gripper_state_right", "gripper_state_left"]
    + [f"object_rot_{a}" for a in "xyz"]
    + [f"object_velp_{a}" for a in "xyz"]
    + [f"object_velr_{a}" for a in "xyz"]
    + [f"grip_velp_{a}" for a in "xyz"]
    + ["gripper_vel_right", "gripper_vel_left"]
)
GOAL_FEATURES = tuple([f"achieved_goal_{a}" for a in "xyz"] + [f"desired_goal_{a}" for a in "xyz"])
GRIP_POS, OBJECT_POS, OBJECT_REL_POS = slice(0, 3), slice(3, 6), slice(6, 9)


@dataclass(frozen=True)
class Controller:
    """The scripted controller's settings; actions are in the environment's units (1.0 = 5 cm per step)."""

    gain: float = 6.0  # action = gain * position error (m), as in baselines
    hover_height: float = 0.03  # reach aims this far above the block
    reach_tolerance: float = 0.005
    grasp_tolerance: float = 0.005
    # baselines uses 1 cm; under MuJoCo 3 the held block sags and creeps to an airborne goal, so 1 cm is
    # reached after the episode's end in about 1 episode in 7. 2 cm gives every phase in ~97 % of episodes.
    transport_tolerance: float = 0.02
    open_command: float = 0.05
    close_command: float = -0.005
    motion_noise: float = 0.02  # std of Gaussian noise added to each motion command (1 mm per step)

    def next_phase(self, phase: int, observation: np.ndarray, goal: np.ndarray) -> int:
        """Advance past every phase whose target the observation already meets (phases never go back)."""
        if phase == REACH and np.linalg.norm(self._hover_error(observation)) < self.reach_tolerance:
            phase = GRASP
        if phase == GRASP and np.linalg.norm(observation[OBJECT_REL_POS]) < self.grasp_tolerance:
            phase = TRANSPORT
        if phase == TRANSPORT and np.linalg.norm(goal - observation[OBJECT_POS]) < self.transport_tolerance:
            phase = PLACE
        return phase

    def action(self, phase: int, observation: np.ndarray, goal: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The 4-value action (dx, dy, dz, gripper) for one step of ``phase``, noise included."""
        if phase == REACH:
            motion, gripper = self.gain * self._hover_error(observation), self.open_command
        elif phase == GRASP:
            motion, gripper = self.gain * observation[OBJECT_REL_POS], self.close_command
        elif phase == TRANSPORT:
            motion, gripper = self.gain * (goal - observation[OBJECT_POS]), self.close_command
        else:
            motion, gripper = np.zeros(3), self.close_command
        motion = motion + rng.normal(0.0, self.motion_noise, size=3)
        return np.clip(np.append(motion, gripper), -1.0, 1.0)

    def _hover_error(self, observation: np.ndarray) -> np.ndarray:
        return observation[OBJECT_REL_POS] + np.array([0.0, 0.0, self.hover_height])


@dataclass(frozen=True)
class Demonstration:
    """One episode: per step the observation, goals and phase label before the action; and its success."""

    observations: np.ndarray  # (steps, 25)
    goals: np.ndarray  # (steps, 6): achieved then desired goal
    labels: np.ndarray  # (steps,)
    success: bool


def make_env() -> Any:
    """FetchPickAndPlace-v4 without rendering (one per collection, reused across episodes)."""
    import gymnasium as gym

    with contextlib.redirect_stderr(io.StringIO()):  # silence a notice about the unrelated Adroit envs
        import gymnasium_robotics
    gym.register_envs(gymnasium_robotics)
    return gym.make(ENV_ID, render_mode=None, max_episode_steps=EPISODE_STEPS)


def demonstrate(env: Any, reset_seed: int, rng: np.random.Generator, controller: Controller) -> Demonstration:
    """Run one scripted episode from the environment's reset with ``reset_seed``."""
    obs, _ = env.reset(seed=reset_seed)
    observations, goals, labels = [], [], []
    phase, info = REACH, {}
    for _ in range(EPISODE_STEPS):
        observation, goal = obs["observation"], obs["desired_goal"]
        phase = controller.next_phase(phase, observation, goal)
        observations.append(observation)
        goals.append(np.concatenate([obs["achieved_goal"], goal]))
        labels.append(phase)
        obs, _, _, _, info = env.step(controller.action(phase, observation, goal, rng))
    return Demonstration(np.asarray(observations), np.asarray(goals), np.asarray(labels), bool(info["is_success"]))


def episode_seeds(seed: int, episode: int) -> tuple[int, np.random.Generator]:
    """The reset seed and noise generator of one episode: independent of the other episodes and seeds."""
    reset_seq, noise_seq = np.random.SeedSequence((seed, episode)).spawn(2)
    return int(reset_seq.generate_state(1)[0]), np.random.default_rng(noise_seq)


def versions() -> dict[str, str]:
    return {name: importlib_metadata.version(name) for name in ("gymnasium-robotics", "gymnasium", "mujoco")}


def simulate(
    episodes: int, seed: int, progress: Callable[[int, int], None] | None = None, controller: Controller = Controller()
) -> list[Demonstration]:
    """Run ``episodes`` scripted demonstrations; episode ``e`` depends only on ``(seed, e)``."""
    env = make_env()
    try:
        demos = []
        for episode in range(episodes):
            reset_seed, rng = episode_seeds(seed, episode)
            demos.append(demonstrate(env, reset_seed, rng, controller))
            if progress is not None:
                progress(episode + 1, episodes)
    finally:
        env.close()
    return demos


# --- the episode cache --------------------------------------------------------------------------------

CACHE_ARRAYS = ("observations", "goals", "labels", "success")


def cache_path(cache: Path, episodes: int, seed: int, controller: Controller) -> Path:
    """The cache file of one collection: named by a digest of all that decides its episodes."""
    key = {
        "env_id": ENV_ID, "episode_steps": EPISODE_STEPS, "episodes": episodes, "seed": seed,
        "controller": asdict(controller), "source": artifacts.file_digest(Path(__file__)),
        "versions": {**versions(), "numpy": np.__version__},
    }
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    return Path(cache) / f"fetch-{episodes}x{seed}-{digest}.npz"


def demonstrations(
    episodes: int, seed: int, progress: Callable[[int, int], None] | None = None,
    controller: Controller = Controller(), cache: Path | None = None,
) -> list[Demonstration]:
    """:func:`simulate`, or the same episodes read back from ``cache`` when simulated there before."""
    if cache is None:
        return simulate(episodes, seed, progress, controller)
    path = cache_path(cache, episodes, seed, controller)
    if path.exists():
        return _read_cache(path)
    demos = simulate(episodes, seed, progress, controller)
    with artifacts.atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:  # a file object: np.savez would append .npz to the temporary name
            np.savez(handle, **{name: np.stack([getattr(d, name) for d in demos]) for name in CACHE_ARRAYS})
    return demos


def _read_cache(path: Path) -> list[Demonstration]:
    try:
        with np.load(path, allow_pickle=False) as saved:
            arrays = [saved[name] for name in CACHE_ARRAYS]
    except Exception as error:  # numpy raises several types for a damaged archive
        raise BadInput(f"{path} is not a readable episode cache ({error}); delete it to simulate again") from error
    return [Demonstration(o, g, y, bool(s)) for o, g, y, s in zip(*arrays)]


def collect(options: Any, progress: Callable[[int, int], None] | None = None) -> Collected:
    """Simulate ``options.episodes`` Fetch demonstrations (or read them from ``options.cache``); the first
    ``options.train_frames`` frames form the train split, ``options.goals`` adds the goal values."""
    controller = Controller()
    demos = demonstrations(options.episodes, options.seed, progress, controller, options.cache)
    steps = EPISODE_STEPS
    n_frames = options.episodes * steps
    train_frames = DEFAULT_TRAIN_FRAMES if options.train_frames is None else options.train_frames
    values = np.concatenate([d.observations for d in demos])
    features = list(OBSERVATION_FEATURES)
    if options.goals:
        values = np.concatenate([values, np.concatenate([d.goals for d in demos])], axis=1)
        features += GOAL_FEATURES
    frames = artifacts.frames_table(
        {
            "episode": np.repeat(np.arange(options.episodes), steps),
            "frame": np.tile(np.arange(steps), options.episodes),
            "label": np.concatenate([d.labels for d in demos]),
            "split": split_by_position(n_frames, train_frames),
        },
        {name: values[:, i] for i, name in enumerate(features)},
    )
    successes = [d.success for d in demos]
    meta = {
        "source": "fetch",
        "env_id": ENV_ID,
        "versions": versions(),
        "classes": list(CLASSES),
        "features": features,
        "train_frames": train_frames,
        "episode_steps": steps,
        "rate_hz": RATE_HZ,
        "controller": asdict(controller),
        "success_rate": float(np.mean(successes)),
        "episode_success": successes,
    }
    return Collected(frames, meta)
