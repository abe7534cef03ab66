"""binarize --suggest's library (mlnseq.predicates.suggest) and the per-class table (predicates.separation) on
the real DESK Taurus kinematics: 14 channels of two arms, grippers 30 (closed) .. 100 (open)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq import binarize, collect
from mlnseq.catalog import artifacts
from mlnseq.predicates import separation, suggest
from mlnseq.predicates.spec import Bins, Change, Gripper, Pair, parse_spec


@pytest.fixture(scope="module")
def kinematics(tmp_path_factory, shared_data) -> Path:
    workdir = tmp_path_factory.mktemp("kinematics")
    collect.run(workdir, collect.CollectOptions(env="desk", source=shared_data / "desk-taurus", channels="kinematics",
                                                train_frames=1000))
    return workdir


def test_the_suggested_spec_parses_as_written_and_finds_the_grippers_and_the_arms_distance(kinematics, tmp_path):
    frames = pl.read_parquet(kinematics / artifacts.FRAMES)
    text = suggest.suggest_spec(frames, "desk")
    spec = parse_spec(text, tmp_path / "s.toml")
    kinds = {p.name: type(p) for p in spec.predicates}
    assert kinds == {"left_gripper_opening": Gripper, "right_gripper_opening": Gripper,
                     "left_right_distance_change": Change, "grippers": Pair}
    assert [c.name for c in spec.channels] == ["between_left_and_right"]
    assert spec.channels[0].start == ("left_x", "left_y", "left_z")
    left = next(p for p in spec.predicates if p.name == "left_gripper_opening")
    train = frames.filter(pl.col("split") == "train")["left_gripper_opening"].to_numpy()
    low, high = np.quantile(train, [0.02, 0.98])  # thresholds from the training split only
    assert left.closed_below == pytest.approx(low + 0.25 * (high - low), rel=1e-5)
    assert left.open_above == pytest.approx(high - 0.25 * (high - low), rel=1e-5)
    # every other channel's change and level are written commented out; switched on, they parse too
    switched_on = re.sub(r"(?m)^# (\[\[predicate\]\]|[a-z_]+ = )", r"\1", text)
    every = parse_spec(switched_on, tmp_path / "all.toml")
    assert {type(p) for p in every.predicates} == {Gripper, Change, Bins, Pair}
    assert len([p for p in every.predicates if isinstance(p, Bins)]) == 13  # 12 channels and the distance


def test_without_grippers_or_points_every_channel_changes(kinematics, tmp_path):
    frames = pl.read_parquet(kinematics / artifacts.FRAMES).select(
        "episode", "frame", "label", "split", "left_angle_1", "left_angle_2", "right_angle_3")
    spec = parse_spec(suggest.suggest_spec(frames, "desk"), tmp_path / "s.toml")
    assert [(type(p), p.channel) for p in spec.predicates] == [
        (Change, "left_angle_1"), (Change, "left_angle_2"), (Change, "right_angle_3")]
    changes = np.abs(np.diff(frames.filter(pl.col("split") == "train")["left_angle_1"].to_numpy()))
    assert spec.predicates[0].threshold == pytest.approx(np.median(changes), rel=1e-5)


def test_binarize_suggest_writes_the_spec_and_uses_it_and_the_class_table_marks_exchange(kinematics, tmp_path):
    written = tmp_path / "mine.binarize.toml"
    _, made = binarize.run(kinematics, binarize.BinarizeOptions(suggest=written))
    assert made.meta["spec"]["path"] == str(written.resolve()) and written.read_text() == made.meta["spec"]["text"]
    _, again = binarize.run(kinematics, binarize.BinarizeOptions(spec=written))
    assert again.predicates.equals(made.predicates)
    binarize.run(kinematics, binarize.BinarizeOptions(suggest=written))  # a suggestion as it was: made again
    written.write_text(written.read_text() + "# my note\n")
    with pytest.raises(binarize.BadInput, match="was edited since it was suggested"):  # edits are never lost silently
        binarize.run(kinematics, binarize.BinarizeOptions(suggest=written))
    assert written.read_text().endswith("# my note\n")
    binarize.run(kinematics, binarize.BinarizeOptions(suggest=written, replace=True))  # --force
    assert "# my note" not in written.read_text()
    columns = [c for group in made.meta["predicates"].values() for c in group]
    shares = separation.class_shares(made.predicates, columns, made.meta["classes"])
    assert shares.shares.shape == (len(columns), 7)
    exchange = shares.classes.index("S5 transfer peg: exchange")
    column, inside, elsewhere = shares.marker(exchange)
    assert column == "grippers_closed_closed" and inside > 0.3 and elsewhere == 0.0  # only S5 closes both


@pytest.mark.mujoco
def test_fetch_grippers_are_the_finger_openings_not_their_rates_and_points_are_positions(fetch_frames_workdir, tmp_path):
    frames = pl.read_parquet(fetch_frames_workdir / artifacts.FRAMES)
    spec = parse_spec(suggest.suggest_spec(frames, "fetch"), tmp_path / "s.toml")
    assert [(type(p), getattr(p, "channel", None)) for p in spec.predicates] == [
        (Gripper, "gripper_state_right"), (Gripper, "gripper_state_left"),
        (Change, "between_grip_pos_and_object_pos"), (Pair, None)]
    assert [(c.start, c.end) for c in spec.channels] == [
        (("grip_pos_x", "grip_pos_y", "grip_pos_z"), ("object_pos_x", "object_pos_y", "object_pos_z"))]
