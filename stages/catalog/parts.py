"""The parts a frame row belongs to: its split in frames.parquet (train, test), and what training and
cross-validation make of the training rows. The values are the strings the artifacts and arrays hold."""

from __future__ import annotations

from enum import StrEnum


class Part(StrEnum):
    TRAIN = "train"  # the training split (frames.parquet), or a training row no part below claims
    TEST = "test"  # the test split: only ever scored, never fitted or chosen on
    FIT = "fit"  # training rows a network is fitted on
    VAL = "val"  # the validation part: training rows held out of fitting, scored each epoch, chosen on
    UNUSED = "unused"  # training rows left out by --train-fraction
    HELDOUT = "heldout"  # a fold's rows, which its fold network and fold MLN are fitted without
