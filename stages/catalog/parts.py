"""The parts a frame row belongs to: its split in frames.parquet (train, test, unlabelled), and what training and
cross-validation make of the training rows. The values are the strings the artifacts and arrays hold."""

from __future__ import annotations

from enum import StrEnum

import polars as pl


class Part(StrEnum):
    TRAIN = "train"  # the training split (frames.parquet), or a training row no part below claims
    TEST = "test"  # the test split: only ever scored, never fitted or chosen on
    UNLABELLED = "unlabelled"  # recordings without labels (null label): never in a split, a fold, a score or a figure
    FIT = "fit"  # training rows a network is fitted on
    VAL = "val"  # the validation part: training rows held out of fitting, scored each epoch, chosen on
    UNUSED = "unused"  # training rows left out by --train-fraction
    HELDOUT = "heldout"  # a fold's rows, which its fold network and fold MLN are fitted without


def labelled(frames: pl.DataFrame) -> pl.DataFrame:
    """The rows of frames.parquet that carry a label: every stage learns, chooses and scores on these alone."""
    return frames.filter(pl.col("split") != Part.UNLABELLED)


def label_mismatch(frames: pl.DataFrame) -> tuple[pl.Series, str]:
    """Rows whose label disagrees with their split, and how: empty on a labelled row, else set on an unlabelled one."""
    unlabelled = (frames["split"] == Part.UNLABELLED).fill_null(False)
    empty = frames["label"].is_null() & ~unlabelled
    return (empty, "empty") if empty.any() else (frames["label"].is_not_null() & unlabelled, "set on an unlabelled row")
