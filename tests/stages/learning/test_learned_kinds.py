"""Each kind of predicate `binarize --suggest` learns separates classes that only it can, on a small generated
recording: a level (stumps), a change over a window (at the scale the channel moves, through noise larger than its
motion per frame), a gripper (a dead band below its motion per frame) and the distance between two 3-D points.
Scored as the search scores a set: the MLN of the per-frame template and learned transitions, cross-validated by
episode with the thresholds learned again without each fold (recognition/learned_logic.py)."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from mlnseq.learning import candidates as kinds
from mlnseq.predicates.spec import Bins, Change, Gripper
from mlnseq.learning import learned_logic

EPISODES, PHASE = 6, 40  # frames per phase: each episode is A, B, A, B


def recording(channels: dict[str, np.ndarray], labels: np.ndarray) -> pl.DataFrame:
    n = len(labels)
    episode = np.repeat(np.arange(EPISODES), n // EPISODES)
    frame = np.tile(np.arange(n // EPISODES), EPISODES)
    return pl.DataFrame({"episode": episode, "frame": frame, "label": labels, "split": ["train"] * n,
                         **{name: values.astype(np.float32) for name, values in channels.items()}})


def alternating(rng: np.random.Generator) -> np.ndarray:
    return np.tile(np.repeat([0, 1, 0, 1], PHASE), EPISODES)


def scored(frames: pl.DataFrame, kind: str | None, channel: str | None = None) -> tuple[float, object]:
    """Cross-validated frame accuracy (%) of the MLN with the one candidate of ``kind`` (on ``channel``; None: no
    predicate, the transitions alone)."""
    data = learned_logic.training(frames, 2)
    found, _ = learned_logic.channels(frames)
    made = [c for c in learned_logic.candidates_of(found, data.frames)
            if c.kind == kind and (channel is None or c.channel == channel)][:1]
    if kind is not None and not made:
        return 0.0, None
    figures, _ = learned_logic.exact(made, [], data)
    return figures["frame_accuracy"], made[0].predicate if made else None


@pytest.fixture(scope="module")
def rng():
    return np.random.default_rng(4)


def test_a_level_cut_where_the_classes_separate(rng):
    labels = alternating(rng)
    x = np.where(labels == 1, 5.0, 0.0) + rng.normal(0, 1.0, len(labels))  # where the arm is decides
    frames = recording({"joint": x}, labels)
    level, predicate = scored(frames, "level")
    change, _ = scored(frames, "change")
    assert isinstance(predicate, Bins) and 1.5 < predicate.edges[0] < 3.5
    assert level > 95 and level > change + 5 and scored(frames, None)[0] < 60, (level, change)


def test_a_change_over_the_window_the_channel_moves_at(rng):
    labels = alternating(rng)
    slope = np.where(labels == 1, 0.01, -0.01)  # rising in B, falling in A, from wherever an episode starts
    x = np.concatenate([rng.uniform(-5, 5) + np.cumsum(slope[k:k + 4 * PHASE])
                        for k in range(0, len(labels), 4 * PHASE)]) + rng.normal(0, 0.01, len(labels))
    frames = recording({"joint": x}, labels)
    change, predicate = scored(frames, "change")
    level, _ = scored(frames, "level")
    assert isinstance(predicate, Change) and predicate.window > 1  # noise as large as its motion per frame
    assert change > 85 and level < 75, (change, level)


def test_a_gripper_with_a_dead_band_below_its_motion_per_frame(rng):
    labels = np.tile(np.repeat([0, 1, 0, 1], PHASE), EPISODES)  # A: closing, B: opening, between the same levels
    steps = np.where(labels == 1, 1.0, -1.0) * 0.001  # 0.001 per frame, as a gripper moves
    width = np.concatenate([0.04 + np.cumsum(steps[k:k + 4 * PHASE]) for k in range(0, len(labels), 4 * PHASE)])
    width = np.clip(width, 0.0, 0.08) + rng.normal(0, 0.0001, len(labels))
    frames = recording({"gripper_width": width + 0.05}, labels)
    gripper, predicate = scored(frames, "gripper")
    assert isinstance(predicate, Gripper) and 0 < predicate.threshold < 0.001  # below its motion per frame
    assert gripper > 90 and scored(frames, None)[0] < 60, gripper
    values = frames["gripper_width"].to_numpy().astype(np.float64)
    changes = np.diff(values, prepend=values[0])
    wide = kinds.gripper_codes(values, changes, predicate.open_above, predicate.closed_below, 0.004)
    assert not np.isin(wide, [2, 3]).any()  # a dead band above its motion (5 % of its range): never opening, closing


def test_the_distance_between_two_points_where_neither_point_does(rng):
    labels = alternating(rng)
    n = len(labels)
    start = rng.uniform(-1, 1, (EPISODES, 3)).repeat(n // EPISODES, axis=0) + rng.normal(0, 0.01, (n, 3))
    direction = rng.normal(0, 1, (n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    end = start + direction * np.where(labels == 1, 0.1, 0.5)[:, None]  # near in B, far in A, anywhere
    frames = recording({f"left_{a}": start[:, i] for i, a in enumerate("xyz")}
                       | {f"right_{a}": end[:, i] for i, a in enumerate("xyz")}, labels)
    distance, predicate = scored(frames, "level", "between_left_and_right")
    alone = max(scored(frames, "level", f"{arm}_{a}")[0] for arm in ("left", "right") for a in "xyz")
    assert predicate is not None and predicate.channel == "between_left_and_right"
    assert distance > 95 and alone < 75 and scored(frames, None)[0] < 60, (distance, alone)


def arm_view(episodes: int = 4) -> tuple[kinds.Frames, dict[str, np.ndarray]]:
    """The generated arm's channels (tests/arm_bags.py) and the search's view of them, 4 episodes all training."""
    import arm_bags

    signals = [arm_bags.episode_signals(arm_bags.ROBOTS["xarm7"], 300 + k) for k in range(episodes)]
    frames = arm_bags.frames_table(signals, ["train"] * episodes)
    data = learned_logic.training(frames, len(arm_bags.PHASES))
    return data.frames, {c: frames[c].to_numpy().astype(np.float64) for c in ("x1", "x7", "x15", "x21")}


def test_every_dead_band_window_and_cut_is_scored_as_coding_every_frame_with_it_scores(rng):
    """The binned scans (one histogram per window, or per gripper) give each threshold the gain, to the bit, that
    coding every frame with it gives: on the arm's joint position, velocity, effort and gripper, in every fold."""
    from dataclasses import replace

    view, channels = arm_view()
    for frames in [view] + [replace(view, train=fold.fit) for fold in learned_logic.folding.masks(view.fold)]:
        for name, values in channels.items():
            for window in kinds.WINDOWS:
                delta = values - kinds.looked_back(values, frames.first, window)
                delta[frames.first] = 0.0
                tried = np.unique(np.quantile(np.abs(delta[frames.train]), np.linspace(0.1, 0.9, 9)))
                alone = [kinds.gain_of(kinds.change_codes(delta, t), frames) for t in tried]
                assert kinds.change_gains(delta, tried, frames).tolist() == alone, (name, window)
            delta = values - kinds.looked_back(values, frames.first, 1)
            delta[frames.first] = 0.0
            open_above, threshold = np.quantile(values[frames.train], 0.9), np.quantile(np.abs(delta), 0.5)
            cuts = np.quantile(values[frames.train], np.linspace(0, 0.9, 12))
            alone = [kinds.gain_of(kinds.gripper_codes(values, delta, open_above, c, threshold), frames) for c in cuts]
            assert kinds.closed_gains(values, delta, open_above, cuts, threshold, frames).tolist() == alone, name


def test_a_long_training_split_is_searched_on_whole_episodes_of_every_fold():
    """Beyond the frames the search reads, it draws whole episodes evenly from each of the folds `mlnseq fit` cuts on
    the whole split (its record, so each fold's predicates are learned without that fold's episodes) and says so."""
    import arm_bags

    slow = arm_bags.at_rate("xarm7", 15.0)  # short episodes: about 160 frames
    signals = [arm_bags.episode_signals(slow, 400 + k) for k in range(12)]
    frames = arm_bags.frames_table(signals, ["train"] * 10 + ["test"] * 2)
    train = frames.filter(pl.col("split") == "train")
    whole = learned_logic.folding.assign(frames["episode"].to_numpy(), frames["split"].to_numpy(),
                                         frames["label"].to_numpy(), 5)
    searched = learned_logic.search(frames, len(arm_bags.PHASES), most=train.height // 2)
    drawn = searched.frames
    assert searched.sampled == (drawn["episode"].n_unique(), 10) and 5 <= searched.sampled[0] < 10
    assert searched.fold_record == whole.record() and (drawn["split"] == "train").all()
    assert drawn.height <= train.height // 2 * 1.3
    for episode in drawn["episode"].unique():  # whole episodes, in order
        assert drawn.filter(pl.col("episode") == episode)["frame"].to_list() == \
            frames.filter(pl.col("episode") == episode)["frame"].to_list()
    folds_drawn = {int(whole.fold[np.flatnonzero(frames["episode"].to_numpy() == e)[0]]) for e in drawn["episode"]}
    assert folds_drawn == set(range(5)) and searched.predicates
    assert learned_logic.training(frames, len(arm_bags.PHASES), most=train.height).sampled is None
