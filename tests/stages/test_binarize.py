"""binarize: the default specs reproduce the published codes; every predicate is one-hot; spec errors say where."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from pathlib import Path

from mlnseq.catalog import artifacts
from mlnseq import collect
from mlnseq.sources.fetch import OBSERVATION_FEATURES
from mlnseq import binarize as stage
from mlnseq.catalog.errors import BadInput
from mlnseq.predicates.rules import StreamingBinarizer

DESK_GRIPPER_CODE = {"static": 0, "open": 1, "closed": 2, "opening": 3, "closing": 4}
DESK_ARM_CODE = {"static": 0, "increase": 1, "decrease": 2}
FETCH_GRIPPER_CODE = {"static": 0, "decrease": 1, "increase": 2}
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def codes(predicates: pl.DataFrame, name: str, columns: list[str], code_of: dict[str, int]) -> np.ndarray:
    """The published-style integer code of a one-hot predicate."""
    values = [c.removeprefix(f"{name}_") for c in columns]
    index = predicates.select(columns).to_numpy().argmax(axis=1)
    return np.array([code_of[values[i]] for i in index])


@pytest.fixture(scope="module")
def desk_frames(shared_data):
    options = collect.CollectOptions(env="desk", source=shared_data / "desk-taurus")
    return collect.collect(options).frames


def fetch_frames(shared_data, episode_length: int | None = None) -> pl.DataFrame:
    """fetch_kinematics_train.txt (25 observation values, label) as frames: one episode, or ``episode_length`` long."""
    table = np.loadtxt(shared_data / "gym-fetch-v1" / "fetch_kinematics_train.txt")
    n = len(table)
    row = np.arange(n)
    episode = np.zeros(n) if episode_length is None else row // episode_length
    frame = row if episode_length is None else row % episode_length
    keys = {"episode": episode, "frame": frame, "label": table[:, -1], "split": np.full(n, "train")}
    return artifacts.frames_table(keys, dict(zip(OBSERVATION_FEATURES, table[:, :25].T)))


def assert_one_hot(predicates: pl.DataFrame, spec: stage.PredicateSpec) -> None:
    for name, columns in spec.columns().items():
        counts = predicates.select(pl.sum_horizontal(columns).alias("n"))["n"]
        assert (counts == 1).all(), f"{name}: {counts.value_counts()}"


def test_default_desk_spec_reproduces_the_published_codes(desk_frames, shared_data):
    spec = stage.load_spec(stage.default_spec_path("desk"))
    predicates = stage.binarize(desk_frames, spec)
    columns = spec.columns()
    assert predicates.columns[:4] == list(artifacts.KEY_COLUMNS)
    for episode, name in enumerate(("taurus_motion_train.txt", "taurus_motion_test.txt")):
        published = np.loadtxt(shared_data / "desk-taurus" / name)
        mine = predicates.filter(pl.col("episode") == episode)
        arm = codes(mine, "arm_distance", columns["arm_distance"], DESK_ARM_CODE)
        left = codes(mine, "left_gripper", columns["left_gripper"], DESK_GRIPPER_CODE)
        right = codes(mine, "right_gripper", columns["right_gripper"], DESK_GRIPPER_CODE)
        np.testing.assert_array_equal(arm[2:], published[2:, 1])
        np.testing.assert_array_equal(left[2:], published[2:, 3])
        np.testing.assert_array_equal(right[2:], published[2:, 5])
        # the pair is the conjunction: grippers_<left>_<right>
        left_value = {code: value for value, code in DESK_GRIPPER_CODE.items()}
        pair = [f"grippers_{left_value[a]}_{left_value[b]}" for a, b in published[2:, [3, 5]].astype(int)]
        pair_true = mine.slice(2).select(columns["grippers"]).to_numpy()
        chosen = np.array(columns["grippers"])[pair_true.argmax(axis=1)]
        assert list(chosen) == pair
        assert (mine["label"].to_numpy() == published[:, 6]).all()
    assert_one_hot(predicates, spec)
    assert "grippers_closed_closed" in columns["grippers"]


def test_default_fetch_spec_reproduces_the_published_gripper_code(shared_data):
    frames = fetch_frames(shared_data)
    spec = stage.load_spec(stage.default_spec_path("fetch"))
    predicates = stage.binarize(frames, spec)
    published = np.loadtxt(shared_data / "gym-fetch-v1" / "fetch_motion_train.txt")
    mine = codes(predicates, "gripper", spec.columns()["gripper"], FETCH_GRIPPER_CODE)
    np.testing.assert_array_equal(mine[2:], published[2:, 0])
    assert set(np.unique(mine)) == {0, 1, 2}
    assert_one_hot(predicates, spec)


def test_an_episodes_first_frame_has_no_previous_frame(shared_data):
    # 126 frames = demonstrations of 50 steps; the published code compares frame 50 with frame 49 of the
    # previous demonstration (the finger fell: code 1), mlnseq calls each episode's first frame static.
    frames = fetch_frames(shared_data, episode_length=50)
    published = np.loadtxt(shared_data / "gym-fetch-v1" / "fetch_motion_train.txt")
    predicates = stage.binarize(frames, stage.load_spec(stage.default_spec_path("fetch")))
    first = predicates.filter(pl.col("frame") == 0)
    assert first["gripper_static"].all() and first.height == 3
    assert published[50, 0] == 1
    second = predicates.filter(pl.col("frame") == 1)  # compares with frame 0; published compared with itself
    assert second["gripper_increase"].all()
    assert (published[[1, 51], 0] == [0, 2]).all()


def test_rich_fetch_spec_names_the_missing_goal(shared_data):
    frames = fetch_frames(shared_data)
    spec = stage.load_spec(EXAMPLES / "fetch-rich.binarize.toml")
    where = r"fetch-rich\.binarize\.toml:\d+: key 'to' of \[\[channel\]\] 'object_goal_distance'"
    with pytest.raises(BadInput, match=rf"{where}.*'desired_goal_x'.*--goals"):
        stage.binarize(frames, spec)


def test_rich_fetch_spec_is_one_hot_and_follows_the_task(shared_data):
    frames = fetch_frames(shared_data, episode_length=50)
    # A goal for the check: where each demonstration left the object (successful demonstrations end there).
    final = frames.group_by("episode").agg(pl.col(f"object_pos_{a}").last().alias(f"desired_goal_{a}") for a in "xyz")
    frames = frames.join(final, on="episode", how="left", maintain_order="left")
    spec = stage.load_spec(EXAMPLES / "fetch-rich.binarize.toml")
    predicates = stage.binarize(frames, spec)
    assert_one_hot(predicates, spec)
    shares = predicates.group_by("label").agg(
        pl.col("object_lifted", "gripper_closed", "gripper_to_object_at").mean()
    ).sort("label")
    reach, _, transport, place = shares.iter_rows(named=True)
    assert reach["object_lifted"] == 0 and transport["object_lifted"] == 1 and place["object_lifted"] == 1
    assert transport["gripper_closed"] == 1 and transport["gripper_to_object_at"] == 1
    assert reach["gripper_to_object_at"] == 0
    assert predicates.filter(pl.col("label") == 3)["object_to_goal_at"].all()


def test_bins_edges_and_the_change_dead_band():
    frames = artifacts.frames_table(
        {"episode": [0] * 5, "frame": range(5), "label": [0] * 5, "split": ["train"] * 5},
        {"x": [0.0, 0.5, 0.5, 1.0, 0.999]},
    )
    spec = stage.parse_spec(
        '[[predicate]]\nname = "level"\nkind = "bins"\nchannel = "x"\nedges = [0.5, 1.0]\n'
        'values = ["low", "mid", "high"]\n'
        '[[predicate]]\nname = "x"\nkind = "change"\nchannel = "x"\nthreshold = 0.0011\n',
        stage.Path("inline.toml"),
    )
    predicates = stage.binarize(frames, spec)
    assert predicates["level_low"].to_list() == [True, False, False, False, False]
    assert predicates["level_high"].to_list() == [False, False, False, True, False]  # an edge opens the upper bin
    assert predicates["x_increase"].to_list() == [False, True, False, True, False]
    assert predicates["x_static"].to_list() == [True, False, True, False, True]  # 0.001 is inside the dead band


VALID = '[[predicate]]\nname = "g"\nkind = "change"\nchannel = "left_gripper"\nthreshold = 0.05\n'


def test_unknown_channel_names_the_line_and_the_known_channels(tmp_path, desk_frames):
    path = tmp_path / "my.binarize.toml"
    path.write_text("# arms\n" + VALID.replace('"left_gripper"', '"left_grip"'))
    with pytest.raises(BadInput, match=rf"^{path}:5: key 'channel'.*'left_grip'.*arm_distance, left_gripper"):
        stage.binarize(desk_frames, stage.load_spec(path))


def test_run_writes_nothing_on_a_bad_spec(tmp_path, desk_frames):
    artifacts.write_table(desk_frames, tmp_path / artifacts.FRAMES, "frames", {"source": "desk", "classes": []})
    bad = tmp_path / "bad.binarize.toml"
    bad.write_text(VALID.replace("0.05", "-0.05"))
    with pytest.raises(BadInput):
        stage.run(tmp_path, stage.BinarizeOptions(spec=bad))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.binarize.toml", artifacts.FRAMES]


def test_distance_channel_rebuilds_the_arm_distance_code_from_the_kinematics(shared_data):
    options = collect.CollectOptions(env="desk", source=shared_data / "desk-taurus", channels="kinematics")
    frames = collect.collect(options).frames
    spec = stage.parse_spec(
        '[[channel]]\nname = "arms"\nkind = "distance"\nfrom = ["left_x", "left_y", "left_z"]\n'
        'to = ["right_x", "right_y", "right_z"]\ndecimals = 2\n'
        '[[predicate]]\nname = "arm_distance"\nkind = "change"\nchannel = "arms"\nthreshold = 0.001\n',
        stage.Path("inline.toml"),
    )
    predicates = stage.binarize(frames, spec)
    published = np.loadtxt(shared_data / "desk-taurus" / "taurus_motion_train.txt")
    mine = codes(predicates, "arm_distance", spec.columns()["arm_distance"], DESK_ARM_CODE)
    np.testing.assert_array_equal(mine[2:], published[2:, 1])


def streamed(frames: pl.DataFrame, spec: stage.PredicateSpec) -> np.ndarray:
    """Every frame through a StreamingBinarizer, reset at each episode's first frame."""
    features = artifacts.feature_columns(frames)
    binarizer = StreamingBinarizer(spec, features)
    values = frames.select(features).to_numpy().astype(np.float64)
    episodes = frames["episode"].to_numpy()
    rows = []
    for i in range(frames.height):
        if i == 0 or episodes[i] != episodes[i - 1]:
            binarizer.reset()
        rows.append(binarizer.step(values[i]))
    return np.array(rows)


def test_streaming_binarizer_matches_the_batch_one_on_real_frames(desk_frames, shared_data):
    desk_spec = stage.load_spec(stage.default_spec_path("desk"))  # gripper with previous_scale 100, a pair
    desk = desk_frames.head(3000)
    batch = stage.binarize(desk, desk_spec).select(pl.exclude(artifacts.KEY_COLUMNS)).to_numpy()
    np.testing.assert_array_equal(streamed(desk, desk_spec), batch)
    rich = stage.load_spec(EXAMPLES / "fetch-rich.binarize.toml")  # distances, bins, change
    goals = ("achieved_goal_x", "achieved_goal_y", "achieved_goal_z", "desired_goal_x", "desired_goal_y", "desired_goal_z")
    fetch = fetch_frames(shared_data, episode_length=50)
    fetch = fetch.with_columns([pl.col(f"object_pos_{a}").alias(f"{kind}_goal_{a}") for kind in ("achieved", "desired")
                                for a in "xyz"]).select(*artifacts.KEY_COLUMNS, *OBSERVATION_FEATURES, *goals)
    batch = stage.binarize(fetch, rich).select(pl.exclude(artifacts.KEY_COLUMNS)).to_numpy()
    assert batch.any(axis=0).sum() > 5  # several predicates vary on these frames
    np.testing.assert_array_equal(streamed(fetch, rich), batch)


def test_a_change_over_a_window_is_the_same_frame_by_frame_and_over_episodes(desk_frames):
    spec = stage.parse_spec('[[predicate]]\nname = "arm"\nkind = "change"\nchannel = "arm_distance"\n'
                            'threshold = 0.01\nwindow = 6\n', stage.Path("inline.toml"))
    desk = desk_frames.head(600).with_columns((pl.arange(0, 600) // 150).alias("episode").cast(pl.Int32))
    batch = stage.binarize(desk, spec).select(pl.exclude(artifacts.KEY_COLUMNS)).to_numpy()
    np.testing.assert_array_equal(streamed(desk, spec), batch)
    x = desk["arm_distance"].to_numpy().astype(np.float64)
    start = np.arange(600) // 150 * 150  # each frame's episode's first frame
    delta = x - x[np.maximum(np.arange(600) - 6, start)]  # 6 frames back, or the episode's first frame
    expected = np.select([delta > 0.01, delta < -0.01], [1, 2], 0)
    np.testing.assert_array_equal(batch.argmax(axis=1), expected)
    assert (expected != np.select([np.diff(x, prepend=x[0]) > 0.01, np.diff(x, prepend=x[0]) < -0.01], [1, 2], 0)).any()
