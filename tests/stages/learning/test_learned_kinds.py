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
