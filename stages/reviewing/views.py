"""What the review page shows, as JSON-ready data: the recordings' table (id, length, how sure the model is, rank
to label) and one recording's view (its channels decimated for drawing, the decided phases, the true and saved
labels, the chosen class's probability). Pure functions on arrays; stages/review.py reads and serves them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mlnseq.timeline import sequences

BUCKETS = 1000  # a channel is drawn from at most 2 points (its min and max) per bucket: a plot's width in pixels


@dataclass(frozen=True)
class Decided:
    """One recording as the model decided it."""

    id: str
    time: np.ndarray  # [T] the recording's clock
    features: np.ndarray  # [T, F] the model's features, raw
    path: np.ndarray  # [T] the decided class indices
    probabilities: np.ndarray  # [T, C]
    labels: np.ndarray | None  # [T] the true labels' class indices (-1: none), if the recording has labels
    origin: str | None = None  # where those labels came from (a fit's workdir says: its own, estimated, ...)
    proposal: np.ndarray | None = None  # [T] the phases a fit proposes to correct (-1: none), if it proposes any
    audit: dict | None = None  # its audit (verdict, score, rank, reasons with start and stop frames), if the model can

    @property
    def confidence(self) -> float:
        """How sure the model is: the mean probability of the class it chose."""
        chosen = self.probabilities[np.arange(len(self.path)), self.path]
        return float(np.mean(chosen)) if len(chosen) else 0.0


def decimated(values: np.ndarray, buckets: int = BUCKETS) -> np.ndarray:
    """The rows to draw a long channel with: each bucket's min and max (a spike survives), the first and the last;
    every row of a short one. NaN rows (a channel not yet heard) are skipped."""
    n = len(values)
    if n <= 2 * buckets:
        return np.arange(n)
    size = math.ceil(n / buckets)
    padded = np.full(size * buckets, np.nan)
    padded[:n] = values
    blocks = padded.reshape(buckets, size)
    finite = np.isfinite(blocks)
    low = np.where(finite, blocks, np.inf).argmin(1)
    high = np.where(finite, blocks, -np.inf).argmax(1)
    offsets = np.arange(buckets) * size
    keep = np.concatenate([[0, n - 1], offsets + low, offsets + high])
    keep = np.unique(keep[keep < n])
    return keep[np.isfinite(values[keep])]


def runs(classes: np.ndarray) -> list[list[int]]:
    """The runs of one class as [first row, last row, class] (class -1: no label there)."""
    classes = np.asarray(classes)
    return [[run.start, run.stop - 1, int(classes[run.start])] for run in sequences.runs(classes)]


def table(recordings: list[Decided], ranks: dict[str, tuple[int, str]], saved: set[str]) -> list[dict]:
    """The recordings' rows: id, frames, seconds, confidence, rank (1 first) and why, labelled (and where its labels
    came from), saved, and the audit's verdict, score and first reason where the model audits.
    ``ranks``: the workdir's label_next.csv (episode: rank, reason), whose recordings come first in its order; the
    others after them, the most suspect first where the model audits (else the least sure first)."""
    others = sorted((i for i, r in enumerate(recordings) if r.id not in ranks), key=lambda i: _suspicion(recordings[i]))
    after = max((rank for rank, _ in ranks.values()), default=0)
    rows = []
    for index, recording in enumerate(recordings):
        if recording.id in ranks:
            rank, reason = ranks[recording.id]
        else:
            rank = after + others.index(index) + 1
            reason = ("ranked by the audit (the most suspect first)" if recording.audit is not None else
                      "ranked by how sure the model is (the least sure first)")
        time, audit = recording.time, recording.audit
        first = audit["reasons"][0] if audit and audit["reasons"] else None
        rows.append({"index": index, "id": recording.id, "frames": int(len(time)),
                     "seconds": float(time[-1] - time[0]) if len(time) else 0.0,
                     "confidence": round(recording.confidence, 4), "rank": int(rank), "reason": reason,
                     "labelled": recording.labels is not None and bool((recording.labels >= 0).any()),
                     "origin": recording.origin, "saved": recording.id in saved,
                     "verdict": audit["verdict"] if audit else None, "score": audit["score"] if audit else None,
                     "why": f"{first['reason']} ({first['where']})" if first else None})
    return sorted(rows, key=lambda row: (row["rank"], row["index"]))


def _suspicion(recording: Decided) -> tuple[float, float]:
    """The order of recordings no ranking names: the audit's rank (the most suspect first), else how sure the model
    is (the least sure first)."""
    return (recording.audit["rank"], 0.0) if recording.audit is not None else (0, recording.confidence)


def _rounded(values: np.ndarray) -> list:
    """Floats for JSON, 6 significant digits (a pixel needs 4); NaN as null."""
    return [None if not math.isfinite(v) else float(f"{v:.6g}") for v in values.tolist()]


def view(recording: Decided, features: list[str], classes: list[str], saved: np.ndarray | None,
         buckets: int = BUCKETS) -> dict:
    """One recording's view: times (every frame's, so an edit lands on a frame), each channel's decimated rows and
    values, the decided phases, the true labels (and where they came from), the proposed phases and the saved labels
    as runs, and the chosen class's probability."""
    chosen = recording.probabilities[np.arange(len(recording.path)), recording.path]
    at = decimated(chosen, buckets)
    channels = []
    for k, name in enumerate(features):
        rows = decimated(recording.features[:, k], buckets)
        channels.append({"name": name, "rows": rows.tolist(), "values": _rounded(recording.features[rows, k])})
    labels = recording.labels if recording.labels is not None and (recording.labels >= 0).any() else None
    return {"id": recording.id, "classes": classes, "time": recording.time.astype(float).tolist(),
            "channels": channels, "phases": runs(recording.path),
            "labels": None if labels is None else runs(labels), "origin": recording.origin,
            "proposal": None if recording.proposal is None else runs(recording.proposal),
            "saved": None if saved is None else runs(saved), "audit": recording.audit,
            "probability": {"rows": at.tolist(), "values": _rounded(chosen[at])}}
