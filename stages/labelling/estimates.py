"""Few labels turned into many at collect: the boundaries between clicks learned (``clicks.py``), then, where asked,
the recordings without labels labelled by aligning them in time to the labelled ones (``alignment.py``); and how many
frames were so estimated (``counted``), which fit says beside figures scored against them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog.parts import Part
from mlnseq.labelling import alignment, clicks
from mlnseq.sources.recording import clicked_episodes


def estimated(frames: pl.DataFrame, meta: dict[str, Any], align: bool) -> tuple[pl.DataFrame, alignment.Aligned | None]:
    """frames.parquet's ``frames`` with the labels the few given ones say (``meta``: its metadata, told how, under
    ``clicks_filled`` and ``aligned``), and what alignment did (None: not asked, or nothing to label)."""
    if meta.get("clicks"):  # one click per phase: where each phase ends, learned from the recordings
        frames, meta["clicks_filled"] = clicks.fill(frames, meta["clicks"], meta["features"])
    if not align or not meta.get("unlabelled_episodes"):
        return frames, None
    clicked = set(clicked_episodes(meta.get("clicks", [])))
    frames, aligned = alignment.label_unlabelled(frames, meta["features"], len(meta["classes"]), clicked)
    meta["aligned"] = aligned.record()
    return frames, aligned


@dataclass(frozen=True)
class Estimated:
    """How many of frames.parquet's labelled frames fit estimated rather than was given: between clicks (the clicked
    frames themselves given) and by alignment; and how many training recordings the user labelled on every frame."""

    between_clicks: int
    by_alignment: int
    exact_recordings: int

    @property
    def frames(self) -> int:
        return self.between_clicks + self.by_alignment

    def said(self) -> str:
        """What the estimated frames are, in words."""
        parts = [f"{self.between_clicks:,} between clicks" if self.between_clicks else "",
                 f"{self.by_alignment:,} by alignment" if self.by_alignment else ""]
        return " and ".join(part for part in parts if part)


def counted(frames: pl.DataFrame, meta: dict[str, Any]) -> Estimated:
    """frames.parquet's estimated frames and the training recordings labelled on every frame by the user."""
    episodes, labelled = frames["episode"].to_numpy(), frames["label"].is_not_null().to_numpy()
    clicked = clicked_episodes(meta.get("clicks", []))
    names = meta.get("episode_names", [])  # none for a dataset (fetch, desk): nothing was estimated
    bare = [k for k, name in enumerate(names) if name in set(meta.get("unlabelled_episodes", []))]
    between = int(np.isin(episodes, clicked).sum()) - len(meta.get("clicks", []))
    aligned = int((np.isin(episodes, bare) & labelled).sum())
    training = set(frames.filter(pl.col("split") == Part.TRAIN.value)["episode"].unique().to_list())
    return Estimated(between, aligned, len(training - set(clicked) - set(bare)))
