"""A learned predicate's comment says what its out-of-fold gain means when it is below 0 (issue 55: a kept
predicate read "out-of-fold gain -0.418 nats" with no word on why it was kept)."""

from __future__ import annotations

import numpy as np
import polars as pl

from mlnseq.learning.candidates import Candidate
from mlnseq.learning.learned_spec import predicate_block
from mlnseq.predicates.spec import Bins


def candidate(frames: pl.DataFrame, oof: float) -> Candidate:
    """The DESK arm distance cut at its training median, as the learner writes a level."""
    distance = frames["arm_distance"].to_numpy()
    median = float(np.median(distance[frames["split"].to_numpy() == "train"]))
    codes = (distance > median).astype(np.int64)
    return Candidate(Bins("arm_distance_level", "arm_distance", (median,), ("near", "far")), "arm_distance", "level",
                     codes, gain=0.05, oof=oof)


def test_a_negative_out_of_fold_gain_is_said_in_words(desk_frames_workdir):
    frames = pl.read_parquet(desk_frames_workdir / "frames.parquet")
    train = frames["split"].to_numpy() == "train"
    labels, classes = frames["label"].to_numpy(), [f"c{k}" for k in range(7)]
    negative = "\n".join(predicate_block(candidate(frames, -0.418), labels, train, classes))
    assert "out-of-fold gain -0.418 nats per frame (below 0: alone, it predicts the held-out frames' classes worse" \
           in negative.replace("\n# ", " ")
    positive = "\n".join(predicate_block(candidate(frames, 0.107), labels, train, classes)).replace("\n# ", " ")
    assert "out-of-fold gain 0.107 nats per frame" in positive and "below 0" not in positive
