"""Recordings without labels labelled by aligning them in time to the labelled ones (labelling/alignment.py), on the
generated arm's episodes (tests/arm_bags.py): the pairing is monotone and whole, its labels are right on most
frames, and recordings are left unlabelled when the labelled ones do not align with each other."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog.artifacts import feature_columns
from mlnseq.catalog.parts import Part
from mlnseq.labelling import alignment

SEED = 7700


def episodes(count: int, robot: str = "panda") -> list[dict[str, np.ndarray]]:
    import arm_bags

    return [arm_bags.episode_signals(arm_bags.ROBOTS[robot], SEED + k) for k in range(count)]


def frames_of(signals: list[dict[str, np.ndarray]], splits: list[str]) -> pl.DataFrame:
    import arm_bags

    return arm_bags.frames_table(signals, splits)


def test_a_path_pairs_every_row_in_order_and_follows_a_stretch():
    a = np.sin(np.linspace(0, 6, 80))[:, None]
    b = np.sin(np.r_[np.linspace(0, 3, 40), np.full(30, 3.0), np.linspace(3, 6, 40)])[:, None]  # a pause in the middle
    ours, theirs = alignment.warping_path(a, b)
    assert (ours[0], theirs[0], ours[-1], theirs[-1]) == (0, 0, 79, 109)
    assert (np.diff(ours) >= 0).all() and (np.diff(theirs) >= 0).all() and (np.diff(ours) + np.diff(theirs) > 0).all()
    assert set(ours) == set(range(80)) and set(theirs) == set(range(110))
    paused = theirs[(theirs >= 45) & (theirs < 65)]  # the pause's frames all pair with a's frames around the turn
    assert np.ptp(ours[np.isin(theirs, paused)]) <= 3


def test_labels_aligned_from_one_recording_are_right_on_most_frames():
    signals = episodes(3)
    frames = frames_of(signals, [Part.TRAIN, Part.UNLABELLED, Part.UNLABELLED])
    filled, aligned = alignment.label_unlabelled(frames, feature_columns(frames), 5)
    assert (aligned.labelled, aligned.templates, aligned.right_when_left_out) == (2, 1, None)  # one labelled: nothing to check
    assert set(filled["split"]) == {Part.TRAIN} and filled["label"].null_count() == 0
    truth = np.concatenate([s["phase"] for s in signals])
    right = filled["label"].to_numpy() == truth
    assert right[filled["episode"].to_numpy() > 0].mean() > 0.93
    assert "2 recordings without labels labelled by aligning each to the 1 labelled training recording" in (
        aligned.said())


def test_the_labelled_recordings_are_checked_on_each_other_and_test_ones_never_used():
    signals = episodes(5)
    frames = frames_of(signals, [Part.TRAIN, Part.TRAIN, Part.TEST, Part.UNLABELLED, Part.UNLABELLED])
    filled, aligned = alignment.label_unlabelled(frames, feature_columns(frames), 5)
    assert (aligned.labelled, aligned.templates) == (2, 2) and aligned.right_when_left_out > alignment.TRUSTED
    assert f"come out {aligned.right_when_left_out:.1%} right" in aligned.said()
    assert filled.filter(pl.col("episode") == 2).equals(frames.filter(pl.col("episode") == 2))  # the test recording


def test_a_recording_partly_in_a_test_split_is_never_aligned_to():
    frames = frames_of(episodes(3), [Part.TRAIN, Part.TRAIN, Part.UNLABELLED])
    first = frames["episode"] == 0
    tested = pl.when(first & (pl.col("frame") >= first.sum() * 7 // 10)).then(pl.lit(Part.TEST.value))
    split = frames.with_columns(split=tested.otherwise(pl.col("split")))  # the first's last 30 %: a test split
    filled, aligned = alignment.label_unlabelled(split, feature_columns(split), 5)
    assert (aligned.labelled, aligned.templates) == (1, 1)  # the second alone is aligned to
    assert filled.filter(pl.col("episode") < 2).equals(split.filter(pl.col("episode") < 2))
    assert alignment.training_recordings(split, leaving_out={1}) == []


def test_recordings_labelled_by_clicks_are_aligned_to_but_not_checked():
    signals = episodes(4)
    reversed_phases = dict(signals[2], phase=4 - signals[2]["phase"])  # clicked, its boundaries placed all wrong
    frames = frames_of([signals[0], signals[1], reversed_phases, signals[3]], [Part.TRAIN] * 3 + [Part.UNLABELLED])
    _, all_right = alignment.label_unlabelled(frames, feature_columns(frames), 5)
    filled, aligned = alignment.label_unlabelled(frames, feature_columns(frames), 5, clicked={2})
    assert all_right.right_when_left_out < alignment.TRUSTED < aligned.right_when_left_out  # the check: the two labelled by hand alone
    assert (aligned.labelled, aligned.templates, aligned.clicked) == (1, 3, 1)
    assert "to the 3 labelled training recordings (1 of them by clicks)" in aligned.said()
    one_by_hand = frames.filter(pl.col("episode") != 1)
    _, on_one = alignment.label_unlabelled(one_by_hand, feature_columns(one_by_hand), 5, clicked={2})
    assert on_one.right_when_left_out is None  # nothing to check it on


def test_labelled_recordings_that_do_not_align_leave_the_others_unlabelled():
    signals = episodes(3)
    reversed_phases = dict(signals[1], phase=4 - signals[1]["phase"])  # the same task labelled in reverse order
    frames = frames_of([signals[0], reversed_phases, signals[2]], [Part.TRAIN, Part.TRAIN, Part.UNLABELLED])
    filled, aligned = alignment.label_unlabelled(frames, feature_columns(frames), 5)
    assert aligned.labelled == 0 and aligned.right_when_left_out < alignment.TRUSTED and filled.equals(frames)
    assert aligned.said().startswith("not labelled by alignment: aligned to each other, the labelled ones come out")


def test_long_recordings_are_aligned_every_kth_frame_and_still_labelled_whole(monkeypatch):
    signals = episodes(2)
    monkeypatch.setattr(alignment, "MOST_CELLS", 20_000)  # about 140 x 140 pairs: every 4th frame or so
    frames = frames_of(signals, [Part.TRAIN, Part.UNLABELLED])
    filled, _ = alignment.label_unlabelled(frames, feature_columns(frames), 5)
    labels = filled.filter(pl.col("episode") == 1)["label"].to_numpy()
    assert len(labels) == len(signals[1]["phase"]) and (labels == signals[1]["phase"]).mean() > 0.9


@pytest.mark.parametrize("splits", [[Part.UNLABELLED, Part.UNLABELLED], [Part.TRAIN, Part.TRAIN]])
def test_nothing_to_align_to_or_nothing_to_label_changes_nothing(splits):
    frames = frames_of(episodes(2), splits)
    filled, aligned = alignment.label_unlabelled(frames, feature_columns(frames), 5)
    assert filled.equals(frames) and aligned.labelled == 0


def test_on_a_dataset_lerobot_wrote_one_annotated_episode_labels_the_others_mostly_right(shared_data):
    from mlnseq import collect
    from mlnseq.sources import SourceOptions

    read = collect.collect(collect.CollectOptions(env="lerobot", source=shared_data / "lerobot-0.6.1" /
                                                  "pick-place-annotated",
                                                  recordings=SourceOptions(annotations="subtask")))
    frames, classes = read.frames, read.meta["classes"]
    first = frames["episode"].min()
    bare = frames.with_columns(split=pl.when(pl.col("episode") == first).then(pl.lit("train"))
                               .otherwise(pl.lit("unlabelled")))
    bare = bare.with_columns(label=pl.when(pl.col("split") == "train").then(pl.col("label")))
    filled, aligned = alignment.label_unlabelled(bare, feature_columns(bare), len(classes))
    others = frames["episode"] != first
    assert aligned.labelled == frames["episode"].n_unique() - 1
    right = (filled["label"].filter(others) == frames["label"].filter(others)).mean()
    assert right > 0.85  # 94.0 % when written
