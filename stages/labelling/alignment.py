"""Labels for recordings without them, from the labelled ones: each recording without labels is aligned in time to
every labelled training recording (dynamic time warping of the standardised features: the least summed distance
over monotone pairings of their frames, so that phases keep their order and may last longer or shorter), and each
of its frames takes the class the labelled frames paired with it hold, by vote over the labelled recordings.

Channels differ in how closely two recordings follow each other: a joint's speed does, its position also says where
the object lay. So the channels are weighted as a Gaussian would weigh its noise: aligned once, each channel is
divided by the spread of its differences along the pairings, and aligned again (``ROUNDS`` times; no label used).

Alignment assumes the recordings perform one task the same way (phases in one order). With two labelled training
recordings or more this is checked on them first: each is aligned to the others as if it had no labels, and the
recordings without labels are labelled only when ``TRUSTED`` of its frames or more come out right; else they stay
unlabelled. Recordings labelled by clicks (``clicks.py``) are aligned to, but not checked: their labels between
clicks were placed by aligning them to the others, so they would pass the check whatever it measures. Test
recordings, and recordings partly in a test split, are never aligned to."""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
import polars as pl

from mlnseq.catalog.parts import Part

TRUSTED = 0.8  # the share of a labelled recording's frames its alignment to the others must get right
MOST_CELLS = 2_500_000  # pairs of frames one alignment compares; longer recordings are aligned every k-th frame
ROUNDS = 3  # of weighting the channels by their spread along the pairings, each followed by aligning again
WEIGHING_PAIRS = 12  # at most this many pairs of recordings measure the channels' spreads
MOST_TEMPLATES = 8  # labelled recordings a recording is aligned to, spread over them in order
PARTNERS = 8  # other recordings each clicked recording is aligned to in time, without recordings labelled whole


@dataclass(frozen=True)
class Aligned:
    """What alignment did: how many recordings it labelled (0: none), and the check on the labelled ones."""

    labelled: int
    templates: int
    right_when_left_out: float | None = None  # the share of labelled frames their alignment to the others got right
    clicked: int = 0  # of the templates, those labelled by clicks (not checked)

    def said(self) -> str:
        check = ("" if self.right_when_left_out is None else
                 f"aligned to each other, the labelled ones come out {self.right_when_left_out:.1%} right")
        if not self.labelled:
            return f"not labelled by alignment: {check}, under {TRUSTED:.0%}"
        plural = "s" if self.templates != 1 else ""
        clicked = f" ({self.clicked} of them by clicks)" if self.clicked else ""
        return (f"{self.labelled:,} recording{'s' if self.labelled != 1 else ''} without labels labelled by "
                f"aligning each to the {self.templates} labelled training recording{plural}{clicked}"
                f"{'; ' + check if check else ''}: they train and enter the folds, never the test split")

    def record(self) -> dict:
        return {"labelled": self.labelled, "templates": self.templates, "clicked": self.clicked,
                "checked": self.right_when_left_out,
                "method": "dynamic time warping of the standardised features, each channel weighted by its spread "
                          "along the pairings; a vote over the labelled recordings"}


def warping_path(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least-cost monotone pairing of the rows of ``a`` [n, F] with those of ``b`` [m, F] (Euclidean distance;
    steps: both, ``a`` alone, ``b`` alone), from (0, 0) to (n-1, m-1), as two index arrays."""
    n, m = len(a), len(b)
    squared = (a * a).sum(axis=1)[:, None] + (b * b).sum(axis=1)[None, :] - 2 * a @ b.T
    cost = np.sqrt(np.maximum(squared, 0.0))
    total = np.full((n + 1, m + 1), np.inf)
    total[0, 0] = 0.0
    for diagonal in range(2, n + m + 1):  # cells on one anti-diagonal depend only on the two before it
        i = np.arange(max(1, diagonal - m), min(n, diagonal - 1) + 1)
        j = diagonal - i
        total[i, j] = cost[i - 1, j - 1] + np.minimum(np.minimum(total[i - 1, j - 1], total[i - 1, j]),
                                                      total[i, j - 1])
    i, j, pairs = n, m, [(n - 1, m - 1)]
    while i > 1 or j > 1:
        steps = ((total[i - 1, j - 1], i - 1, j - 1), (total[i - 1, j], i - 1, j), (total[i, j - 1], i, j - 1))
        _, i, j = min(steps, key=lambda step: step[0])
        pairs.append((i - 1, j - 1))
    pairs.reverse()
    found = np.asarray(pairs)
    return found[:, 0], found[:, 1]


def _every(features: np.ndarray, template: np.ndarray) -> int:
    """The step k at which two recordings are aligned: every frame, or every k-th for at most MOST_CELLS pairs."""
    return max(1, int(np.ceil(np.sqrt(len(features) * len(template) / MOST_CELLS))))


@dataclass(frozen=True)
class Pairing:
    """Two recordings aligned: the frames of ours and of theirs paired along the path, every ``step``-th frame."""

    ours: np.ndarray
    theirs: np.ndarray
    step: int
    length: int  # our frames

    def votes(self, labels: np.ndarray, n_classes: int) -> np.ndarray:
        """[our frames, C]: per frame of ours, the share of their frames paired with it holding each class (their
        ``labels``); between kept frames, the kept frame's."""
        counts = np.zeros((int(self.ours.max()) + 1, n_classes))
        np.add.at(counts, (self.ours, labels[::self.step][self.theirs]), 1.0)
        counts /= counts.sum(axis=1, keepdims=True)
        return np.repeat(counts, self.step, axis=0)[:self.length]

    def ours_at(self, frame: int) -> int:
        """Our frame paired with their ``frame`` (the middle one where several are)."""
        paired = self.ours[self.theirs == min(frame // self.step, int(self.theirs.max()))]
        return min(int(np.median(paired)) * self.step, self.length - 1)


def paired(features: np.ndarray, template: np.ndarray) -> Pairing:
    """``features`` aligned to ``template``; long recordings every k-th frame (at most MOST_CELLS pairs)."""
    step = _every(features, template)
    ours, theirs = warping_path(features[::step], template[::step])
    return Pairing(ours, theirs, step, len(features))


def votes(features: np.ndarray, template: np.ndarray, labels: np.ndarray, n_classes: int) -> np.ndarray:
    """[len(features), C]: per frame, the share of the ``template``'s frames paired with it that hold each class."""
    return paired(features, template).votes(labels, n_classes)


def channel_weights(pairs: list[tuple[np.ndarray, np.ndarray]], rounds: int = ROUNDS) -> np.ndarray:
    """[F]: each channel's weight, 1 / the spread of its differences along the pairings of ``pairs`` (recordings'
    standardised features), re-aligned with the weights each round; scaled to a root mean square of 1."""
    weights = np.ones(pairs[0][0].shape[1])
    for _ in range(rounds):
        spread = []
        for a, b in pairs:
            found = paired(a * weights, b * weights)
            spread.append(((a[::found.step][found.ours] - b[::found.step][found.theirs]) ** 2).mean(axis=0))
        weights = 1.0 / np.sqrt(np.mean(spread, axis=0) + 1e-3)
        weights /= np.sqrt((weights ** 2).mean())
    return weights


def pairings(z: np.ndarray, rows_of: dict[int, np.ndarray]) -> dict[tuple[int, int], Pairing]:
    """Each recording of ``rows_of`` (its rows of ``z``, the standardised features; clicked recordings) aligned to up
    to PARTNERS others (the next ones in order), on the features weighted as ``channel_weights`` weighs them:
    ``{(ours, theirs): Pairing}``."""
    order = list(rows_of)
    partners = {u: [order[(k + d) % len(order)] for d in range(1, min(PARTNERS, len(order) - 1) + 1)]
                for k, u in enumerate(order)}
    weighing = [(z[rows_of[u]], z[rows_of[t]]) for u, ts in partners.items() for t in ts[:1]]
    weighted = z * channel_weights(weighing[:WEIGHING_PAIRS])
    return {(u, t): paired(weighted[rows_of[u]], weighted[rows_of[t]]) for u, ts in partners.items() for t in ts}


def template_votes(features: np.ndarray, templates: list[tuple[np.ndarray, np.ndarray]], n_classes: int) -> np.ndarray:
    """[len(features), C]: the votes of the ``templates`` (features, labels; at most MOST_TEMPLATES of them, spread
    over them in order) aligned to a recording, per frame."""
    spread = templates[::-(-len(templates) // MOST_TEMPLATES)]
    return np.sum([votes(features, f, y, n_classes) for f, y in spread], axis=0)


def transferred(features: np.ndarray, templates: list[tuple[np.ndarray, np.ndarray]], n_classes: int) -> np.ndarray:
    """A recording's labels: the class most of the ``templates`` pair its frames with."""
    return template_votes(features, templates, n_classes).argmax(axis=1)


def right_when_left_out(templates: list[tuple[np.ndarray, np.ndarray]], n_classes: int) -> float:
    """The share of the labelled frames right when each labelled recording is aligned to the others."""
    right = [transferred(f, templates[:k] + templates[k + 1:], n_classes) == y for k, (f, y) in enumerate(templates)]
    return float(np.concatenate(right).mean())


def standardised(frames: pl.DataFrame, features: list[str]) -> np.ndarray:
    """[rows, F]: the ``features`` columns of ``frames`` (frames.parquet) standardised over all its rows."""
    values = frames.select(features).to_numpy().astype(np.float64)
    return (values - values.mean(axis=0)) / (values.std(axis=0) + 1e-9)


def rows_by_recording(episodes: np.ndarray) -> dict[int, np.ndarray]:
    """Each recording's rows of frames.parquet, by episode, in the order they come."""
    return {int(e): np.flatnonzero(episodes == e) for e in dict.fromkeys(episodes.tolist())}


def training_recordings(frames: pl.DataFrame, leaving_out: Collection[int] = ()) -> list[np.ndarray]:
    """The rows of each recording training on every frame (but those of ``leaving_out``): what a recording is aligned
    to; one partly in a test split never is, so that no test label labels another recording."""
    training = (frames["split"] == Part.TRAIN).to_numpy()
    return [rows for episode, rows in rows_by_recording(frames["episode"].to_numpy()).items()
            if episode not in leaving_out and training[rows].all()]


def aligned_votes(z: np.ndarray, bare: list[np.ndarray], known: list[np.ndarray], labels: np.ndarray,
                  n_classes: int, unchecked: list[np.ndarray] = ()) -> tuple[list[np.ndarray] | None, float | None]:
    """Each recording of ``bare`` (its rows of ``z``, the standardised features) aligned to the labelled ones
    ``known`` and ``unchecked``, the channels weighted by their spread along the pairings: its frames' votes
    [frames, C], or None where those of ``known``, aligned to each other, come out under TRUSTED right; and that check
    (None under two)."""
    every = [*known, *unchecked]
    pairs = [(z[u], z[t]) for u in bare for t in every]
    z = z * channel_weights(pairs[::max(1, len(pairs) // WEIGHING_PAIRS)][:WEIGHING_PAIRS])
    templates = [(z[rows], labels[rows]) for rows in every]
    check = right_when_left_out(templates[:len(known)], n_classes) if len(known) > 1 else None
    if check is not None and check < TRUSTED:
        return None, check
    return [template_votes(z[rows], templates, n_classes) for rows in bare], check


def label_unlabelled(frames: pl.DataFrame, features: list[str], n_classes: int,
                     clicked: Collection[int] = ()) -> tuple[pl.DataFrame, Aligned]:
    """frames.parquet with its unlabelled recordings labelled by alignment to the labelled training ones (their split
    then ``train``), and what was done; as it was when there is nothing to align to or the check fails. The episodes
    ``clicked`` (labelled by clicks) are aligned to but not checked."""
    z = standardised(frames, features)
    episodes, splits = frames["episode"].to_numpy(), frames["split"].to_numpy()
    labels = frames["label"].fill_null(-1).to_numpy().astype(np.int64)
    by_hand = training_recordings(frames, leaving_out=clicked)
    by_clicks = [rows for rows in training_recordings(frames) if episodes[rows[0]] in clicked]
    templates = len(by_hand) + len(by_clicks)
    bare = [rows for rows in rows_by_recording(episodes).values() if splits[rows[0]] == Part.UNLABELLED]
    if not templates or not bare:
        return frames, Aligned(0, templates, clicked=len(by_clicks))
    found, check = aligned_votes(z, bare, by_hand, labels, n_classes, unchecked=by_clicks)
    if found is None:
        return frames, Aligned(0, templates, check, len(by_clicks))
    new_splits = splits.astype(object)
    for rows, their_votes in zip(bare, found):
        labels[rows] = their_votes.argmax(axis=1)
        new_splits[rows] = Part.TRAIN.value
    filled = frames.with_columns(label=pl.Series(labels, dtype=frames["label"].dtype),
                                 split=pl.Series(new_splits.astype(str)))
    return filled, Aligned(len(bare), templates, check, len(by_clicks))
