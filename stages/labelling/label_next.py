"""Which recording to label next: the unlabelled recordings ranked by how much labelling each would teach, and the
phases proposed for each (the labels fit trained on, or a model's decoding, whichever fit found better), so that a
user corrects a proposal instead of labelling from nothing.

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

import enum
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.sources.recording import clicked_episodes

MEASURES = ("entropy", "disagreement", "restarts", "distance")


class Proposed(enum.Enum):
    """Which labelling of a recording a proposal starts from (the value: how fit says it)."""

    ESTIMATES = "the labels fit trained on (alignment's, or the clicks' fill)"
    DECODING = "the model's decoding"


def chosen(checked: float | None, decoding: float | None) -> tuple[Proposed, str]:
    """What the proposed phases start from, and why: the labels fit trained on, unless the model's decoding
    cross-validates better (``decoding``: its cross-validated frame accuracy, %) than those labels were checked to be
    (``checked``: alignment's share right on the recordings labelled on every frame, each aligned to the others)."""
    if checked is None:
        return Proposed.ESTIMATES, ("nothing checks them against the decoding below two recordings labelled on every "
                                    "frame")
    versus = f"{100 * checked:.1f} % right when checked, the decoding {decoding:.1f} % cross-validated" if (
        decoding is not None) else f"{100 * checked:.1f} % right when checked, the decoding not cross-validated"
    return (Proposed.DECODING if decoding is not None and decoding > 100 * checked else Proposed.ESTIMATES), versus


@dataclass(frozen=True)
class Proposal:
    """The unlabelled recordings ranked (``label_next.csv``'s rows) and their proposed phases as intervals."""

    ranked: pl.DataFrame  # episode, rank, reason, then the four measures
    intervals: pl.DataFrame  # episode, start, end, label, unit (frames): predict --intervals' form
    clicked: bool = False  # the recordings ranked were labelled by clicks (every one was), to label on every frame
    proposed: Proposed = Proposed.DECODING  # what the phases start from, where a recording has it
    shortest: int = 1  # no run of the proposed phases is shorter (frames; half the shortest labelled phase)
    why: str = ""  # why ``proposed`` (``chosen``'s words)

    @property
    def starts_from(self) -> str:
        """What the proposed phases start from, in words."""
        if self.proposed is Proposed.DECODING:
            return self.proposed.value
        return "the clicks' fill fit trained on" if self.clicked else "alignment's labels fit trained on"

    def first(self, n: int = 3) -> list[str]:
        """The first ``n`` recordings to label, one line each."""
        return [f"{row['rank']}. {row['episode']}: {row['reason']}"
                for row in self.ranked.head(n).iter_rows(named=True)]


def summary(features: np.ndarray) -> np.ndarray:
    """A recording in one vector: each feature's mean and standard deviation."""
    return np.concatenate([features.mean(axis=0), features.std(axis=0)])


def distances(unlabelled: list[np.ndarray], labelled: list[np.ndarray]) -> np.ndarray:
    """Each unlabelled recording's distance to the nearest labelled one (none labelled: the nearest other one), on
    their summaries standardised over every recording (a summary that does not vary among them counts by its own
    unit), so that labelling one more changes the scale little."""
    found = np.stack([summary(f) for f in unlabelled])
    known = np.stack([summary(f) for f in labelled]) if labelled else found
    scale = np.vstack([found, known] if labelled else [found]).std(axis=0)
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
    if not meta.get("clicks"):  # a dataset (fetch, desk) or recordings labelled on every frame
        return [], False
    names = meta["episode_names"]
    clicked = [names[e] for e in clicked_episodes(meta["clicks"])]
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


def place(values: np.ndarray, row: int) -> str:
    """Where ``values[row]`` stands among ``values``, the largest first: "the most of 5", "3rd most of 5, tied", or
    "as all 5" where they are alike."""
    n = len(values)
    if np.all(values == values[0]):
        return f"as all {n}"
    rank = int(np.sum(values > values[row])) + 1
    tied = int(np.sum(values == values[row])) > 1
    ordinal = "the" if rank == 1 else {2: "2nd", 3: "3rd"}.get(rank, f"{rank}th")
    return f"{ordinal} most of {n}{', tied' if tied else ''}"


def _reason(measure: str, value: float, where: str, others: str) -> str:
    if measure == "entropy":
        return f"the chain is unsure: mean posterior entropy {value:.2f} nats ({where})"
    if measure == "disagreement":
        return f"the network and the formulas disagree on {value:.0%} of its frames ({where})"
    if measure == "restarts":
        return f"the decoding broke a rule {value:.0f} time{'s' if value != 1 else ''} ({where})"
    return f"it is the least like {others}: distance {value:.2f} ({where})"


def ranked(table: pl.DataFrame, others: str = "the labelled recordings") -> pl.DataFrame:
    """``table`` (episode and the four measures) ranked: the mean of each measure's rank (0..1), highest first;
    ``others``: what the distance is measured to, in the reasons. A recording's reason is the measure it ranks
    highest on, with its value and its place among them all."""
    n = table.height
    share = {m: (table[m].rank("average").to_numpy() - 1) / max(n - 1, 1) for m in MEASURES}
    score = np.mean([share[m] for m in MEASURES], axis=0)
    reasons = []
    for row in range(n):
        best = max(MEASURES, key=lambda m: (share[m][row], -MEASURES.index(m)))
        values = table[best].to_numpy().astype(np.float64)
        reasons.append(_reason(best, float(values[row]), place(values, row), others))
    order = np.lexsort((np.arange(n), -score))
    return (table.with_columns(pl.Series("score", score), pl.Series("reason", reasons))[order]
            .with_columns(pl.int_range(1, n + 1).alias("rank"))
            .select("episode", "rank", "reason", *MEASURES, "score"))


def runs_of(classes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The runs of one class in ``classes``: their first rows and lengths."""
    starts = np.r_[0, np.flatnonzero(np.diff(classes)) + 1]
    return starts, np.diff(np.r_[starts, len(classes)])


def shortest_phase(labelled: list[np.ndarray]) -> int:
    """The fewest frames a phase lasted in the ``labelled`` recordings (class indices; 1 without any)."""
    return min((int(runs_of(labels)[1].min()) for labels in labelled if len(labels)), default=1)


def shortest_run(labelled: list[np.ndarray]) -> int:
    """The shortest run a proposal keeps: half the shortest phase of the ``labelled`` recordings. A phase lasts
    longer in one recording than in another (the generated arm's grasp: 66 to 89 frames): held to the whole
    shortest, a proposal loses real phases; runs under half of it are flicker."""
    return max(1, shortest_phase(labelled) // 2)


def without_short_runs(classes: np.ndarray, shortest: int) -> np.ndarray:
    """``classes`` with every run shorter than ``shortest`` frames given to the longer run beside it, the shortest
    first (a recording shorter than ``shortest`` keeps one run)."""
    classes = np.array(classes, copy=True)
    while True:
        starts, lengths = runs_of(classes)
        k = int(np.argmin(lengths))
        if len(lengths) == 1 or lengths[k] >= shortest:
            return classes
        beside = [j for j in (k - 1, k + 1) if 0 <= j < len(lengths)]
        into = max(beside, key=lambda j: (lengths[j], -j))
        classes[starts[k]:starts[k] + lengths[k]] = classes[starts[into]]


def propose(recognizer: Any, frames: pl.DataFrame, episode_names: list, without_labels: list,
            clicked: bool = False, proposed: Proposed = Proposed.DECODING, why: str = "") -> Proposal:
    """The recordings of ``frames`` (frames.parquet) named in ``without_labels`` (given no labels: unlabelled, or
    labelled by alignment; or, ``clicked``, all of them, labelled by clicks) ranked against the labelled ones, with
    the phases proposed for each: ``proposed`` (the labels fit trained on, where a recording has them on every frame,
    else the decoding of ``recognizer``, a model file fitted on the workdir), without a run under half the shortest
    phase of the labelled recordings (``shortest_run``)."""
    from mlnseq.sources import intervals

    names = artifacts.feature_columns(frames)
    if list(recognizer.features) != names:
        raise ValueError(f"the model reads {recognizer.features}, the frames hold {names}")
    given_none = set(without_labels)
    unlabelled = frames["episode"].is_in([k for k, name in enumerate(episode_names) if name in given_none])

    def by_episode(rows: pl.DataFrame) -> list[tuple[int, np.ndarray, np.ndarray]]:
        return [(int(e), part.select(names).to_numpy().astype(np.float64),
                 part["label"].fill_null(-1).to_numpy().astype(np.int64))
                for (e,), part in rows.partition_by("episode", as_dict=True, maintain_order=True).items()]

    bare, known = by_episode(frames.filter(unlabelled)), by_episode(frames.filter(~unlabelled))
    shortest = shortest_run([y for _, _, y in (known or bare) if (y >= 0).all()])
    rows, segments = [], []
    for episode, features, labels in bare:
        found = measured(recognizer, features)
        path = found.pop("path")
        start = labels if proposed is Proposed.ESTIMATES and (labels >= 0).all() else path
        classes = [recognizer.classes[int(k)] for k in without_short_runs(np.asarray(start), shortest)]
        name = str(episode_names[episode])
        rows.append({"episode": name, **found})
        segments.append(intervals.segments([name] * len(features), np.arange(len(features)), np.arange(
            len(features), dtype=np.float64), classes, "frames").with_columns(unit=pl.lit("frames")))
    table = pl.DataFrame(rows).with_columns(pl.Series("distance", distances([f for _, f, _ in bare],
                                                                            [f for _, f, _ in known])))
    return Proposal(ranked(table, "the other clicked recordings" if clicked else "the labelled recordings"),
                    pl.concat(segments), clicked, proposed, shortest, why)


def files(workdir: Path) -> tuple[Path, Path]:
    """Where a proposal goes: ``WORKDIR/label_next.csv`` and ``WORKDIR/unlabelled.intervals.csv``."""
    return Path(workdir) / artifacts.LABEL_NEXT, Path(workdir) / artifacts.UNLABELLED_INTERVALS


def write(workdir: Path, proposal: Proposal) -> tuple[Path, Path]:
    """The ranking (episode, rank, reason, the measures) and the proposed phases (episode, start, end, label, unit:
    frames, as the file says) written to their ``files``."""
    paths = files(workdir)
    for table, path in zip((proposal.ranked, proposal.intervals), paths):
        with artifacts.atomic_path(path) as staged:
            table.write_csv(staged, float_precision=4)
    return paths


def remove(workdir: Path) -> list[Path]:
    """A workdir's ranking and proposed phases from an earlier fit, removed (nothing left to rank); those removed."""
    found = list(files(workdir))
    for path in found:
        path.unlink(missing_ok=True)
    return [path for path in found if not path.exists()]
