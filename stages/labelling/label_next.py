"""Which recording to label next: the unlabelled recordings ranked by how much labelling each would teach, and the
phases a model predicts for each, so that a user corrects a proposal instead of labelling from nothing.

Four measures per recording, each from a recogniser fitted on the labelled ones (a model file with both the
network and the MLN): the mean entropy of the decoded posterior (how unsure the chain is), the share of frames
where the network and the MLN's formulas name different classes, the restarts where the decoding had to break a
rule (a dead end), and how far the recording lies from the labelled ones (its features' means and spreads,
standardised, to the nearest labelled recording's). A recording's score is the mean of its ranks on the four
(each 0 to 1, 1 the most to teach); rank 1 is labelled first, and its reason is the measure it ranks highest on.

Where every recording was labelled by clicks, the clicked ones are ranked instead, to label one on every frame: clicks
cannot say where a still stretch between two phases belongs, a recording labelled on every frame does, for all the
others (``clicks.py``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.sources.recording import clicked_episodes

MEASURES = ("entropy", "disagreement", "restarts", "distance")


@dataclass(frozen=True)
class Proposal:
    """The unlabelled recordings ranked (``label_next.csv``'s rows) and their predicted phases as intervals."""

    ranked: pl.DataFrame  # episode, rank, reason, then the four measures
    intervals: pl.DataFrame  # episode, start, end, label: frames, predict --intervals' form
    clicked: bool = False  # the recordings ranked were labelled by clicks (every one was), to label on every frame

    def first(self, n: int = 3) -> list[str]:
        """The first ``n`` recordings to label, one line each."""
        return [f"{row['rank']}. {row['episode']}: {row['reason']}"
                for row in self.ranked.head(n).iter_rows(named=True)]


def summary(features: np.ndarray) -> np.ndarray:
    """A recording in one vector: each feature's mean and standard deviation."""
    return np.concatenate([features.mean(axis=0), features.std(axis=0)])


def distances(unlabelled: list[np.ndarray], labelled: list[np.ndarray]) -> np.ndarray:
    """Each unlabelled recording's distance to the nearest labelled one (none labelled: the nearest other one), on
    their summaries standardised over those it is measured to (a summary that does not vary among them counts by its
    own unit)."""
    found = np.stack([summary(f) for f in unlabelled])
    known = np.stack([summary(f) for f in labelled]) if labelled else found
    scale = known.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    squared = (((found[:, None, :] - known[None, :, :]) / scale) ** 2).mean(axis=2)
    if not labelled:
        np.fill_diagonal(squared, np.inf)
    return np.sqrt(squared.min(axis=1))


def candidates(meta: dict) -> tuple[list, bool]:
    """The recordings to rank (frames.parquet's metadata ``meta``), and whether they are clicked ones: those given
    without labels; else, where every recording was labelled by clicks (two or more), the clicked ones."""
    if meta.get("unlabelled_episodes"):
        return list(meta["unlabelled_episodes"]), False
    names = meta["episode_names"]
    clicked = [names[e] for e in clicked_episodes(meta.get("clicks", []))]
    return (clicked, True) if len(names) > 1 and len(clicked) == len(names) else ([], False)


def measured(recognizer: Any, features: np.ndarray) -> dict[str, float]:
    """One recording's entropy, disagreement and restarts, and its predicted class indices (key ``path``)."""
    scores = recognizer.scored(features, np.zeros(len(features), dtype=np.int64))
    p = np.clip(scores.probabilities, 1e-12, 1.0)
    entropy = float(np.mean(-(p * np.log(p)).sum(axis=1)))
    disagreement = 0.0
    if scores.log_p_network is not None and scores.log_p_mln is not None:
        disagreement = float(np.mean(scores.log_p_network.argmax(axis=1) != scores.log_p_mln.argmax(axis=1)))
    return {"entropy": entropy, "disagreement": disagreement, "restarts": float(len(recognizer.restarts)),
            "path": scores.path}


def _reason(measure: str, value: float, count: int, others: str) -> str:
    if measure == "entropy":
        return f"the chain is unsure: mean posterior entropy {value:.2f} nats (most of {count})"
    if measure == "disagreement":
        return f"the network and the formulas disagree on {value:.0%} of its frames (most of {count})"
    if measure == "restarts":
        return f"the decoding broke a rule {value:.0f} time{'s' if value != 1 else ''} (most of {count})"
    return f"it is the least like {others}: distance {value:.2f} (most of {count})"


def ranked(table: pl.DataFrame, others: str = "the labelled recordings") -> pl.DataFrame:
    """``table`` (episode and the four measures) ranked: the mean of each measure's rank (0..1), highest first;
    ``others``: what the distance is measured to, in the reasons."""
    n = table.height
    share = {m: (table[m].rank("average").to_numpy() - 1) / max(n - 1, 1) for m in MEASURES}
    score = np.mean([share[m] for m in MEASURES], axis=0)
    reasons = []
    for row in range(n):
        best = max(MEASURES, key=lambda m: (share[m][row], -MEASURES.index(m)))
        reasons.append(_reason(best, float(table[best][row]), n, others))
    order = np.lexsort((np.arange(n), -score))
    return (table.with_columns(pl.Series("score", score), pl.Series("reason", reasons))[order]
            .with_columns(pl.int_range(1, n + 1).alias("rank"))
            .select("episode", "rank", "reason", *MEASURES, "score"))


def propose(recognizer: Any, frames: pl.DataFrame, episode_names: list, without_labels: list,
            clicked: bool = False) -> Proposal:
    """The recordings of ``frames`` (frames.parquet) named in ``without_labels`` (given no labels: unlabelled, or
    labelled by alignment; or, ``clicked``, all of them, labelled by clicks) ranked against the labelled ones, with
    the phases ``recognizer`` (a model file fitted on the workdir) predicts for each."""
    from mlnseq.sources import intervals

    names = artifacts.feature_columns(frames)
    if list(recognizer.features) != names:
        raise ValueError(f"the model reads {recognizer.features}, the frames hold {names}")
    given_none = set(without_labels)
    unlabelled = frames["episode"].is_in([k for k, name in enumerate(episode_names) if name in given_none])

    def by_episode(rows: pl.DataFrame) -> list[tuple[int, np.ndarray]]:
        return [(int(e), part.select(names).to_numpy().astype(np.float64))
                for (e,), part in rows.partition_by("episode", as_dict=True, maintain_order=True).items()]

    bare, known = by_episode(frames.filter(unlabelled)), by_episode(frames.filter(~unlabelled))
    rows, segments = [], []
    for episode, features in bare:
        found = measured(recognizer, features)
        classes = [recognizer.classes[int(k)] for k in found.pop("path")]
        name = str(episode_names[episode])
        rows.append({"episode": name, **found})
        segments.append(intervals.segments([name] * len(features), np.arange(len(features)), np.arange(
            len(features), dtype=np.float64), classes, "frames"))
    table = pl.DataFrame(rows).with_columns(pl.Series("distance", distances([f for _, f in bare],
                                                                            [f for _, f in known])))
    return Proposal(ranked(table, "the other clicked recordings" if clicked else "the labelled recordings"),
                    pl.concat(segments), clicked)


def write(workdir: Path, proposal: Proposal) -> tuple[Path, Path]:
    """``WORKDIR/label_next.csv`` (episode, rank, reason, the measures) and the predicted phases,
    ``WORKDIR/unlabelled.intervals.csv`` (episode, start, end, label in frames: ``--labels-unit frames``)."""
    workdir = Path(workdir)
    paths = workdir / artifacts.LABEL_NEXT, workdir / artifacts.UNLABELLED_INTERVALS
    for table, path in zip((proposal.ranked, proposal.intervals), paths):
        with artifacts.atomic_path(path) as staged:
            table.write_csv(staged, float_precision=4)
    return paths
