"""The split of collect's labelled frames: the source's own ``split`` column, else a share of the episodes (or, with
few labelled recordings, none spent on a test split: every label learns)."""

from __future__ import annotations

from enum import StrEnum

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput

DEFAULT_TRAIN_SHARE = 0.7


class Holdout(StrEnum):
    """How collect draws its test split from labelled episodes the source gives no split for."""

    SHARE = "share"  # the first 70 % of the labelled episodes train, the rest test (one episode: of its frames)
    UNLESS_FEW = "unless-few"  # as SHARE from FEW_LABELLED labelled episodes on; below, every labelled frame trains
    NONE = "none"  # every labelled frame trains: no test split


FEW_LABELLED = 5  # below this many labelled recordings, UNLESS_FEW spends none on a test split



def split_of(frames: pl.DataFrame, episode_index: np.ndarray, at,
             holdout: Holdout = Holdout.SHARE) -> np.ndarray:
    """A ``split`` column of the source if it has one, else the first 70 % of episodes train (Holdout.UNLESS_FEW:
    every frame trains below FEW_LABELLED episodes).

    With a single episode, the first 70 % of its frames train.
    """
    given = frames["split"]
    if given.is_null().any() and given.is_not_null().any():
        first = frames.filter(given.is_null()).row(0, named=True)
        raise BadInput(f"{at(first)}: empty split; give every row train or test, or drop the column")
    if given.is_not_null().all():
        bad = ~given.is_in(list(artifacts.SPLITS))
        if bad.any():
            first = frames.filter(bad).row(0, named=True)
            raise BadInput(f"{at(first)}: split {first['split']!r} is neither train nor test")
        return given.to_numpy()
    order = np.unique(episode_index, return_inverse=True)[1]  # the labelled episodes numbered 0, 1, ... in order
    n_episodes = int(order.max()) + 1
    if holdout is Holdout.NONE or (holdout is Holdout.UNLESS_FEW and n_episodes < FEW_LABELLED):
        return np.full(len(order), "train")
    if n_episodes == 1:
        position = np.arange(len(order)) < round(DEFAULT_TRAIN_SHARE * len(order))
    else:
        position = order < max(1, round(DEFAULT_TRAIN_SHARE * n_episodes))
    return np.where(position, "train", "test")
