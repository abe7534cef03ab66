"""collect: the DESK import against the shared files, MuJoCo Fetch demonstrations, and atomic writes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog import artifacts
from mlnseq import collect
from mlnseq.sources import desk
from mlnseq.sources import fetch as fetch_demos
from mlnseq.catalog.errors import BadInput

# Reads an artifact with polars, pyarrow and json only, and proves no project module was loaded.
READ_WITHOUT_PROJECT = """
import json, sys
import polars as pl, pyarrow.parquet as pq
path = sys.argv[1]
meta = json.loads(pq.read_schema(path).metadata[b"mlnseq"])
assert json.loads(pl.read_parquet_metadata(path)["mlnseq"]) == meta
frames = pl.read_parquet(path)
assert not any(name.split(".")[0] in ("mlnseq", "mlnseq_cli") for name in sys.modules)
print(json.dumps({"meta": meta, "columns": frames.columns, "dtypes": [str(d) for d in frames.dtypes],
                  "height": frames.height}))
"""


def read_without_project(path: Path) -> dict:
    done = subprocess.run(
        [sys.executable, "-I", "-c", READ_WITHOUT_PROJECT, str(path)],
        capture_output=True, text=True, check=True, cwd=path.parent,
    )
    return json.loads(done.stdout)


def motion_file(shared_data: Path, name: str) -> np.ndarray:
    return np.loadtxt(shared_data / "desk-taurus" / name)


# --- DESK ------------------------------------------------------------------------------------------


def test_desk_import_matches_the_shared_files(desk_frames_workdir, shared_data):
    frames, meta = artifacts.read_table(desk_frames_workdir / artifacts.FRAMES, "frames")
    train = motion_file(shared_data, "taurus_motion_train.txt")
    test = motion_file(shared_data, "taurus_motion_test.txt")
    both = np.concatenate([train, test])

    assert frames.height == 22_329 == len(both)
    assert frames.columns == [*artifacts.KEY_COLUMNS, "arm_distance", "left_gripper", "right_gripper"]
    assert frames.filter(pl.col("split") == "train").height == 1_405
    assert frames.filter(pl.col("split") == "test").height == 20_924
    assert (frames["split"].head(1_405) == "train").all()
    assert frames.group_by("episode").len().sort("episode")["len"].to_list() == [len(train), len(test)]
    np.testing.assert_array_equal(frames["label"].to_numpy(), both[:, -1].astype(np.int16))
    np.testing.assert_array_equal(frames["arm_distance"].to_numpy(), both[:, 0].astype(np.float32))
    np.testing.assert_array_equal(frames["right_gripper"].to_numpy(), both[:, 4].astype(np.float32))
    assert meta["source"] == "desk" and meta["classes"] == list(desk.CLASSES)
    assert sorted(Path(name).name for name in meta["inputs"]) == sorted(desk.MOTION_FILES)


def test_desk_arm_distance_is_the_distance_of_the_kinematics(desk_frames_workdir, shared_data):
    kinematics = collect.collect(
        collect.CollectOptions(env="desk", source=shared_data / "desk-taurus", channels="kinematics")
    ).frames
    assert kinematics.height == 1_405
    assert artifacts.feature_columns(kinematics) == list(desk.KINEMATICS_FEATURES)
    assert len(desk.KINEMATICS_FEATURES) == 14
    assert (kinematics["split"] == "train").all()

    left = kinematics.select("left_x", "left_y", "left_z").to_numpy().astype(np.float64)
    right = kinematics.select("right_x", "right_y", "right_z").to_numpy().astype(np.float64)
    motion, _ = artifacts.read_table(desk_frames_workdir / artifacts.FRAMES, "frames")
    arm_distance = motion.filter(pl.col("episode") == 0)["arm_distance"].to_numpy()
    # the file rounds to 2 decimals; at ~1e5 float32 keeps about 0.01, so compare as float32
    distance = np.round(np.linalg.norm(left - right, axis=1), 2)
    np.testing.assert_array_equal(distance.astype(np.float32), arm_distance)
    np.testing.assert_array_equal(kinematics["label"].to_numpy(), motion["label"].head(1_405).to_numpy())


def test_desk_frames_are_readable_without_project_code(desk_frames_workdir):
    seen = read_without_project(desk_frames_workdir / artifacts.FRAMES)
    assert seen["height"] == 22_329
    assert seen["dtypes"] == ["Int32", "Int32", "Int16", "String", "Float32", "Float32", "Float32"]
    assert seen["meta"]["classes"][0] == "S1 approach peg" and len(seen["meta"]["classes"]) == 7
    assert seen["meta"]["features"] == seen["columns"][4:]


# --- Fetch (MuJoCo) -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fetch_frames(fetch_frames_workdir) -> tuple[pl.DataFrame, dict]:
    return artifacts.read_table(fetch_frames_workdir / artifacts.FRAMES, "frames")


@pytest.mark.mujoco
def test_fetch_frames_schema_and_metadata(fetch_frames, fetch_frames_workdir):
    import mujoco

    frames, meta = fetch_frames
    steps, episodes = fetch_demos.EPISODE_STEPS, meta["options"]["episodes"]
    assert frames.columns == [*artifacts.KEY_COLUMNS, *fetch_demos.OBSERVATION_FEATURES]
    assert len(fetch_demos.OBSERVATION_FEATURES) == 25
    assert frames.dtypes == [pl.Int32, pl.Int32, pl.Int16, pl.String] + [pl.Float32] * 25
    assert frames.height == episodes * steps
    assert frames["episode"].to_list() == [e for e in range(episodes) for _ in range(steps)]
    assert frames["frame"].to_list() == list(range(steps)) * episodes
    assert frames["split"].to_list() == ["train"] * 126 + ["test"] * (frames.height - 126)
    assert meta["classes"] == ["reach", "grasp", "transport", "place"]
    assert meta["source"] == "fetch" and meta["env_id"] == "FetchPickAndPlace-v4"
    assert meta["features"] == list(fetch_demos.OBSERVATION_FEATURES)
    assert meta["versions"]["mujoco"] == mujoco.__version__ and meta["versions"]["gymnasium-robotics"] == "1.4.2"
    assert meta["success_rate"] == np.mean(meta["episode_success"]) and len(meta["episode_success"]) == episodes

    seen = read_without_project(fetch_frames_workdir / artifacts.FRAMES)
    assert seen["columns"] == frames.columns and seen["meta"]["success_rate"] == meta["success_rate"]


@pytest.mark.mujoco
def test_fetch_frames_record_the_simulations_rate_which_turns_a_latency_into_frames(fetch_frames):
    from mlnseq.choosing import latency

    _, meta = fetch_frames
    assert meta["rate_hz"] == pytest.approx(1 / fetch_demos.make_env().unwrapped.dt)  # 0.04 s a step
    assert latency.rate_of(meta) == meta["rate_hz"]
    assert latency.budget_frames(None, 1.0, latency.rate_of(meta), "the workdir") == 25
    assert latency.rate_of({**meta, "rate_hz": None}) is None  # the source's name alone gives no rate


@pytest.mark.mujoco
def test_fetch_labels_run_reach_grasp_transport_place_in_order(fetch_frames):
    frames, _ = fetch_frames
    for (episode,), rows in frames.group_by("episode"):
        labels = rows.sort("frame")["label"].to_numpy()
        assert labels[0] == fetch_demos.REACH, episode
        assert (np.diff(labels) >= 0).all(), f"episode {episode} goes back a phase: {labels}"
        assert set(labels) == {0, 1, 2, 3}, f"episode {episode} misses a phase: {labels}"
        # the paper's phases run about 17/8/17/8 frames
        assert 12 <= np.sum(labels == fetch_demos.REACH) <= 25, labels


@pytest.mark.mujoco
def test_fetch_features_are_named_after_what_they_hold(fetch_frames):
    frames, _ = fetch_frames
    xyz = lambda prefix: frames.select(f"{prefix}_x", f"{prefix}_y", f"{prefix}_z").to_numpy()  # noqa: E731
    np.testing.assert_allclose(xyz("object_rel_pos"), xyz("object_pos") - xyz("grip_pos"), atol=1e-6)
    fingers = frames.select("gripper_state_right", "gripper_state_left").to_numpy()
    transport = frames["label"].to_numpy() == fetch_demos.TRANSPORT
    # carrying the 5 cm block, the two fingers stand about 2.5 cm each from the centre
    assert np.all(np.abs(fingers[transport].sum(axis=1) - 0.05) < 0.01)
    # velocities are displacements per step (25 Hz): grip_velp follows the change of grip_pos
    for axis in "xyz":
        moved = frames.select(
            pl.col(f"grip_pos_{axis}").diff().over("episode").alias("moved"), pl.col(f"grip_velp_{axis}")
        ).drop_nulls()
        assert np.corrcoef(moved.to_numpy().T)[0, 1] > 0.95, axis


@pytest.mark.mujoco
def test_fetch_same_seed_same_frames_other_seed_other_frames(fetch_frames):
    frames, meta = fetch_frames
    seed = meta["seed"]
    calls = []
    again = fetch_demos.collect(
        collect.CollectOptions(episodes=2, seed=seed), progress=lambda done, total: calls.append((done, total))
    ).frames
    assert calls == [(1, 2), (2, 2)]
    # an episode depends only on (seed, episode): a shorter run repeats the longer one's first episodes
    assert again.drop("split").equals(frames.filter(pl.col("episode") < 2).drop("split"))
    other = fetch_demos.collect(collect.CollectOptions(episodes=2, seed=seed + 1)).frames
    assert not np.allclose(other["object_pos_x"].to_numpy(), again["object_pos_x"].to_numpy())


@pytest.mark.mujoco
def test_fetch_goals_and_train_frames_options():
    collected = fetch_demos.collect(collect.CollectOptions(episodes=1, goals=True, train_frames=10))
    frames = collected.frames
    assert collected.meta["features"] == [*fetch_demos.OBSERVATION_FEATURES, *fetch_demos.GOAL_FEATURES]
    assert artifacts.feature_columns(frames) == collected.meta["features"]
    assert frames["split"].to_list() == ["train"] * 10 + ["test"] * 40
    achieved = frames.select("achieved_goal_x", "achieved_goal_y", "achieved_goal_z").to_numpy()
    np.testing.assert_array_equal(achieved, frames.select("object_pos_x", "object_pos_y", "object_pos_z").to_numpy())
    assert frames.select(pl.col("^desired_goal_.$").n_unique()).row(0) == (1, 1, 1)


def test_collecting_another_dataset_into_a_workdir_says_what_it_replaces_and_what_stays(tmp_path, shared_data):
    workdir = tmp_path / "work"
    collect.run(workdir, collect.CollectOptions(env="desk", source=shared_data / "desk-taurus"))
    (workdir / "learned.binarize.toml").write_text("# learned from the DESK frames\n")
    table = tmp_path / "trial.csv"
    pl.DataFrame({"x": np.linspace(0, 1, 40), "label": ["a"] * 20 + ["b"] * 20}).write_csv(table)
    replacing = collect.CollectOptions(env="table", source=table)

    _, collected = collect.run(workdir, replacing)
    said = [note for note in collected.meta["notes"] if note.startswith("replaced")]
    assert len(said) == 1 and "--env desk" in said[0] and "1 file made from those frames" in said[0]
    assert "learned.binarize.toml" in said[0] and "-w DIR" in said[0]
    _, again = collect.run(workdir, replacing)  # the same source again: nothing replaced to speak of
    assert not [note for note in again.meta["notes"] if note.startswith("replaced")]


# --- atomic writes --------------------------------------------------------------------------------


def test_a_failed_write_leaves_no_partial_frames(tmp_path, monkeypatch, desk_frames_workdir, shared_data):
    def write_half_then_fail(table, where, **kwargs):
        Path(where).write_bytes(b"PAR1 half a file")
        raise RuntimeError("disk vanished mid-write")

    monkeypatch.setattr(artifacts.pq, "write_table", write_half_then_fail)
    options = collect.CollectOptions(env="desk", source=shared_data / "desk-taurus")

    fresh = tmp_path / "fresh"
    with pytest.raises(RuntimeError, match="mid-write"):
        collect.run(fresh, options)
    assert list(fresh.iterdir()) == []

    existing = tmp_path / "existing"
    existing.mkdir()
    before = (desk_frames_workdir / artifacts.FRAMES).read_bytes()
    (existing / artifacts.FRAMES).write_bytes(before)
    with pytest.raises(RuntimeError, match="mid-write"):
        collect.run(existing, options)
    assert [p.name for p in existing.iterdir()] == [artifacts.FRAMES]
    assert (existing / artifacts.FRAMES).read_bytes() == before


# --- the episode cache ----------------------------------------------------------------------------

# Collects through the stage in a fresh process; prints whether the simulator was loaded.
COLLECT_AND_SAY_IF_SIMULATED = """
import json, sys
from pathlib import Path
from mlnseq import collect
options = collect.CollectOptions(**json.loads(sys.argv[2]), cache=Path(sys.argv[3]))
collect.run(Path(sys.argv[1]), options)
print(json.dumps([name for name in ("mujoco", "gymnasium", "gymnasium_robotics") if name in sys.modules]))
"""


def collect_in_process(workdir: Path, cache: Path, **options) -> list[str]:
    done = subprocess.run([sys.executable, "-c", COLLECT_AND_SAY_IF_SIMULATED, str(workdir), json.dumps(options),
                           str(cache)], capture_output=True, text=True, check=True)
    return json.loads(done.stdout)


@pytest.mark.mujoco
def test_fetch_cache_reuses_the_simulated_episodes_for_every_split_and_goal_option(tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")  # byte-identical artifacts but for their inputs
    cache = tmp_path / "cache"
    assert collect_in_process(tmp_path / "first", cache, episodes=3, seed=2) != []  # simulated
    assert len(list(cache.iterdir())) == 1
    assert collect_in_process(tmp_path / "rich", cache, episodes=3, seed=2, goals=True, train_frames=60) == []
    assert collect_in_process(tmp_path / "again", cache, episodes=3, seed=2) == []
    for name, options in (("first", {}), ("rich", {"goals": True, "train_frames": 60})):
        fresh = tmp_path / f"{name}-fresh"
        collect.run(fresh, collect.CollectOptions(episodes=3, seed=2, **options))  # no cache: simulated
        assert (tmp_path / name / artifacts.FRAMES).read_bytes() == (fresh / artifacts.FRAMES).read_bytes(), name
    assert (tmp_path / "again" / artifacts.FRAMES).read_bytes() == (tmp_path / "first" / artifacts.FRAMES).read_bytes()
    assert collect_in_process(tmp_path / "other", cache, episodes=3, seed=3) != []  # another seed: simulated
    assert len(list(cache.iterdir())) == 2


@pytest.mark.mujoco
def test_a_damaged_cache_file_is_named_and_nothing_is_written(tmp_path):
    options = collect.CollectOptions(episodes=1, seed=4, cache=tmp_path / "cache")
    collect.run(tmp_path / "first", options)
    [cached] = (tmp_path / "cache").iterdir()
    cached.write_bytes(cached.read_bytes()[:100])
    with pytest.raises(BadInput, match=f"{cached.name} is not a readable episode cache.*delete it"):
        collect.run(tmp_path / "second", options)
    assert not (tmp_path / "second" / artifacts.FRAMES).exists()
