"""Few labels turned into many at collect: the boundaries between clicks learned (``clicks.py``), then, where asked,
the recordings without labels labelled by aligning them in time to the labelled ones (``alignment.py``)."""

from __future__ import annotations

from typing import Any

import polars as pl

from mlnseq.labelling import alignment, clicks
from mlnseq.sources.recording import clicked_episodes


def estimated(frames: pl.DataFrame, meta: dict[str, Any], align: bool) -> tuple[pl.DataFrame, alignment.Aligned | None]:
    """frames.parquet's ``frames`` with the labels the few given ones say (``meta``: its metadata, told how, under
    ``clicks_filled`` and ``aligned``), and what alignment did (None: not asked, or nothing to label)."""
    if meta.get("clicks"):  # one click per phase: where each phase ends, learned from the recordings
        frames, meta["clicks_filled"] = clicks.fill(frames, meta["clicks"])
    if not align or not meta.get("unlabelled_episodes"):
        return frames, None
    clicked = set(clicked_episodes(meta.get("clicks", [])))
    frames, aligned = alignment.label_unlabelled(frames, len(meta["classes"]), clicked)
    meta["aligned"] = aligned.record()
    return frames, aligned
