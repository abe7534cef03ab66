"""binarize --suggest: what it reads off the columns (mlnseq.learning.suggest; the real DESK Taurus kinematics, 14
channels of two arms, grippers 30 (closed) .. 100 (open)), and the spec and formulas it learns and writes
(recognition/learned_files.py) on a small recording of the generated 7-joint arm (tests/arm_bags.py: 3 training
episodes and a test one), read back as written, from the training split only; and the per-class table."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq import binarize, collect
from mlnseq.catalog import artifacts
from mlnseq.learning import learned_spec, suggest
from mlnseq.predicates import separation
from mlnseq.predicates.spec import parse_spec
from mlnseq.choosing import folds as folding


@pytest.fixture(scope="module")
def kinematics(tmp_path_factory, shared_data) -> Path:
    workdir = tmp_path_factory.mktemp("kinematics")
    collect.run(workdir, collect.CollectOptions(env="desk", source=shared_data / "desk-taurus", channels="kinematics",
                                                train_frames=900))
    return workdir


def arm_frames(seed: int = 5, episodes: int = 4, rate: float = 20.0) -> tuple[pl.DataFrame, dict]:
    """The frames collect would make of ``episodes`` arm episodes (the last one the test split), at ``rate``."""
    import arm_bags

    robot = arm_bags.at_rate("panda", rate)
    tables = []
    for k in range(episodes):
        signals = arm_bags.episode_signals(robot, seed * 100 + k)
        n = len(signals["phase"])
        features = {"/gripper/width/data": signals["width"]} | {
            f"/joint_states/{field}/{joint}": signals[field][:, j] for field in ("position", "velocity", "effort")
            for j, joint in enumerate(robot.joints)}
        tables.append(artifacts.frames_table({"episode": np.full(n, k), "frame": np.arange(n),
                                              "label": signals["phase"], "split": ["train" if k < episodes - 1
                                                                                  else "test"] * n}, features))
    return pl.concat(tables), {"classes": list(arm_bags.PHASES), "source": "rosbag"}


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> Path:
    workdir = tmp_path_factory.mktemp("arm")
    frames, meta = arm_frames()
    artifacts.write_table(frames, workdir / artifacts.FRAMES, "frames", meta)
    return workdir


@pytest.fixture(scope="module")
def learned(arm, tmp_path_factory) -> tuple[Path, binarize.Binarized]:
    spec = tmp_path_factory.mktemp("learned") / "mine.binarize.toml"
    return spec, binarize.run(arm, binarize.BinarizeOptions(suggest=spec))[1]


def gripper_columns(frames: pl.DataFrame, features: list[str]) -> list[str]:
    """The feature columns suggest reads as grippers, on the training split."""
    train = frames.filter(pl.col("split") == "train")
    return [c for c in features if suggest.looks_like_gripper(
        suggest.Channel(c, c, train[c].to_numpy(), np.abs(np.diff(train[c].to_numpy()))))]


def test_the_columns_read_as_grippers_points_and_short_names(kinematics):
    frames = pl.read_parquet(kinematics / artifacts.FRAMES)
    features = artifacts.feature_columns(frames)
    grippers = gripper_columns(frames, features)
    assert grippers == ["left_gripper_opening", "right_gripper_opening"]
    assert suggest.points(features) == [("left", ("left_x", "left_y", "left_z")),
                                        ("right", ("right_x", "right_y", "right_z"))]
    assert suggest.names_for(["/gripper/width/data", "/joint_states/position/j1", "/joint_states/velocity/j1"]) == {
        "/gripper/width/data": "width", "/joint_states/position/j1": "position_j1",
        "/joint_states/velocity/j1": "velocity_j1"}  # a message's generic field names nothing


def test_the_learned_spec_reads_back_as_written_and_says_what_each_predicate_separates(arm, learned):
    spec_path, made = learned
    text = spec_path.read_text()
    assert made.meta["spec"]["text"] == text and learned_spec.untouched(text)
    spec = parse_spec(text, spec_path)
    assert spec.predicates and all(f"name = \"{p.name}\"" in text for p in spec.predicates)
    assert text.count("% of training frames;") == sum(len(p.values) for p in spec.predicates)  # per value
    record = made.meta["learned"]
    assert record["folds"] == "3 folds by episode" and record["predicates"] == [p.name for p in spec.predicates]
    assert record["cross_validated"]["frame_accuracy"] > 80  # five phases: chance is about 20 %
    _, again = binarize.run(arm, binarize.BinarizeOptions(spec=spec_path))
    assert again.predicates.equals(made.predicates)
    formulas = Path(record["formulas"])
    assert formulas.name == "mine.formulas.mln" and "0.0 Has(+w, p) => Topic(+c, p)" in formulas.read_text()


def test_each_fold_has_its_own_predicates_learned_without_it_and_the_test_split_is_never_read(arm, learned, tmp_path):
    spec_path, made = learned
    table, meta = artifacts.read_table(arm / artifacts.FOLD_PREDICATES, "fold_predicates")
    frames = pl.read_parquet(arm / artifacts.FRAMES)
    cut = folding.assign(frames["episode"].to_numpy(), frames["split"].to_numpy(), frames["label"].to_numpy(), 3)
    assert meta["folds"] == cut.record() and table["fold"].unique().sort().to_list() == [0, 1, 2]
    assert table.height == 3 * frames.height and meta["spec_text"] == spec_path.read_text()
    shifted = tmp_path / "shifted"  # the same frames, every test frame's features moved
    shifted.mkdir()
    test = pl.col("split") == "test"
    artifacts.write_table(frames.with_columns(pl.when(test).then(pl.col(c) * 3 + 7).otherwise(pl.col(c)).alias(c)
                                              for c in artifacts.feature_columns(frames)),
                          shifted / artifacts.FRAMES, "frames", artifacts.read_metadata(arm / artifacts.FRAMES))
    other = tmp_path / "other.binarize.toml"
    binarize.run(shifted, binarize.BinarizeOptions(suggest=other))
    assert other.read_text().replace("other.", "mine.") == spec_path.read_text()


def test_an_edited_spec_is_kept_unless_forced_and_the_class_table_reads_its_predicates(arm, learned):
    spec_path, made = learned
    spec_path.write_text(spec_path.read_text() + "# my note\n")
    with pytest.raises(binarize.BadInput, match="was edited since it was learned"):  # edits are never lost silently
        binarize.run(arm, binarize.BinarizeOptions(suggest=spec_path))
    assert spec_path.read_text().endswith("# my note\n")
    columns = [c for group in made.meta["predicates"].values() for c in group]
    shares = separation.class_shares(made.predicates, columns, made.meta["classes"])
    assert shares.shares.shape == (len(columns), 5) and np.allclose(shares.shares[:len(made.meta["predicates"][
        next(iter(made.meta["predicates"]))])].sum(axis=0), 1.0)  # one value of a predicate holds in every frame


@pytest.mark.mujoco
def test_fetch_grippers_are_the_finger_openings_not_their_rates_and_points_are_positions(fetch_frames_workdir):
    frames = pl.read_parquet(fetch_frames_workdir / artifacts.FRAMES)
    features = artifacts.feature_columns(frames)
    grippers = gripper_columns(frames, features)
    assert grippers == ["gripper_state_right", "gripper_state_left"]
    assert [name for name, *_ in suggest.distance_channels(features, set(frames.columns))] == [
        "between_grip_pos_and_object_pos"]
