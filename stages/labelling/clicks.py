"""Where the phases between clicks begin. A clicks file (``episode,frame,label`` or ``time`` rows, each saying "this
frame is in this phase"; read by ``sources/intervals.py``) labels the frames between two clicks of an episode in click
order: the frames up to the first click are its phase, those from the last click on the last's, and between two clicks
of different phases one boundary falls, first put halfway when read. The clicked frames are kept
(``Recording.resolved["clicks"]``, then frames.parquet's metadata ``clicks``: episode, frame, class) so that it says
which labels were given.

Where each boundary falls is then learned: ``fill`` first aligns each clicked recording in time to the others
(``labelling/alignment.py``), then cuts each span to where the others' clicks around a boundary of its kind fall once
aligned (``narrowed``: the boundary comes after their earlier clicks and before their later ones), places the
boundary where the frames left split best into two parts of their own means (the least-squares change point of the
standardised features: the two phases look different, nothing else is assumed), moves each where the frames around
it look most like those around the boundaries of the same kind in the other recordings (``moved_to_their_kind``: a
change point misses each boundary by its own amount, which a network learns as blur; aligned, they miss alike), and
last moves each, between its two clicks, to where its frames agree most with the labels the other recordings pair
with them (``agreed``). The clicked frames never change.

Clicks say which phase a frame is in, not where a phase begins: where a stretch could belong to either phase (a still
arm before the fingers close), those steps give it to one side in every recording alike. Where training recordings
labelled on every frame sit beside the clicked ones, they say it: each clicked recording is then aligned to them as
alignment labels a recording without labels, and each boundary placed, between its two clicks, where their labels
agree most (``alignment.aligned_votes``; the clicked-only steps again if aligning them to each other fails
alignment's check).

A clicked recording always trains (``sources/table.py``): its labels between clicks are estimates, which a test split
would score against. (Re-placing the boundaries from a fitted model's log-probabilities, an EM step, was measured and
did not help.)"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
import polars as pl

from mlnseq.catalog.notes import counted
from mlnseq.catalog.parts import Part
from mlnseq.labelling import alignment
from mlnseq.sources.recording import clicked_episodes

ALIGN_HALF_WIDTH = 10  # frames on each side of a boundary compared with the other boundaries of its kind
ALIGN_ROUNDS = 3  # rounds of moving every boundary to the others' mean window (more drift them together)


@dataclass(frozen=True)
class Span:
    """Where one boundary is learned: the frames ``first`` to ``last`` of ``episode`` between two consecutive clicks in
    different phases, ``before``'s then ``after``'s; the boundary is the first frame of ``after``, in first+1 .. last.
    (Frames within the episode, or, once ``fill`` has them, positions among its rows.)"""

    episode: int
    first: int
    last: int
    before: int
    after: int


class Stretch(NamedTuple):
    """A span's rows (positions among frames.parquet's rows, first to last) and its two phases' classes."""

    rows: np.ndarray
    before: int
    after: int


def free_spans(clicks: list[list[int]]) -> list[Span]:
    """The boundaries to learn: a ``Span`` for every two consecutive clicks (episode, frame, class) of an episode in
    different phases."""
    ordered = sorted(map(tuple, clicks))
    return [Span(e1, f1, f2, c1, c2) for (e1, f1, c1), (e2, f2, c2) in zip(ordered, ordered[1:])
            if e1 == e2 and c1 != c2]


def change_point(z: np.ndarray) -> int:
    """The t in 1 .. n-1 splitting rows ``z`` [n, F] into two parts of least summed squared distance to their means."""
    n = len(z)
    total = np.cumsum(z, axis=0)
    left, sizes = total[:-1], np.arange(1, n)
    right = total[-1] - left
    return int(np.argmax((left * left).sum(axis=1) / sizes + (right * right).sum(axis=1) / (n - sizes))) + 1


def _window(z: np.ndarray, episodes: np.ndarray, row: int, half: int) -> np.ndarray:
    """The rows of ``z`` from ``row - half`` to ``row + half - 1``, those outside ``row``'s episode as ``row``."""
    around = np.clip(np.arange(row - half, row + half), 0, len(z) - 1)
    return z[np.where(episodes[around] == episodes[row], around, row)]


def moved_to_their_kind(z: np.ndarray, episodes: np.ndarray, spans: list[Stretch], cuts: list[int],
                        half: int = ALIGN_HALF_WIDTH, rounds: int = ALIGN_ROUNDS) -> list[int]:
    """Each boundary ``cuts[i]`` (in 1 .. len(rows)-1 of span i) moved, ``rounds`` times, to where the rows around it
    are nearest (least squares) the mean of the rows around the other boundaries of its kind; one alone of its kind
    stays."""
    kinds = [(before, after) for _, before, after in spans]
    for _ in range(rounds):
        windows = [_window(z, episodes, rows[t], half) for (rows, _, _), t in zip(spans, cuts)]
        moved = []
        for i, (rows, _, _) in enumerate(spans):
            others = [w for j, w in enumerate(windows) if j != i and kinds[j] == kinds[i]]
            if not others:
                moved.append(cuts[i])
                continue
            template = np.mean(others, axis=0)
            cost = [((_window(z, episodes, row, half) - template) ** 2).sum() for row in rows[1:]]
            moved.append(int(np.argmin(cost)) + 1)
        cuts = moved
    return cuts


def _stretches(rows_of: dict[int, np.ndarray], spans: list[Span]) -> list[Stretch]:
    return [Stretch(rows_of[s.episode][s.first:s.last + 1], s.before, s.after) for s in spans]


def _relabelled(frames: pl.DataFrame, labels: np.ndarray) -> pl.DataFrame:
    labelled = pl.Series((frames["split"] != Part.UNLABELLED).to_numpy())
    return frames.with_columns(label=pl.when(labelled).then(pl.Series(labels, dtype=pl.Int16)))


def narrowed(spans: list[Span], found: dict[tuple[int, int], alignment.Pairing]) -> list[Span]:
    """Each span cut to where the other recordings' clicks around a boundary of its kind fall once aligned to it: the
    boundary comes after their earlier clicks and before their later ones. The one nearest the boundary on each side
    is let go (a pairing may miss by a few frames); a span is kept whole where they leave no room."""
    own: dict[tuple[int, int, int], list[Span]] = {}
    for span in spans:
        own.setdefault((span.episode, span.before, span.after), []).append(span)
    cut = []
    for span in spans:
        earlier, later = [span.first], [span.last]
        for (ours, theirs), pairing in found.items():
            theirs_spans = own.get((theirs, span.before, span.after), [])
            if ours == span.episode and len(theirs_spans) == 1:
                earlier.append(pairing.ours_at(theirs_spans[0].first))
                later.append(pairing.ours_at(theirs_spans[0].last))
        low = max(span.first, sorted(earlier)[-2]) if len(earlier) > 2 else span.first
        high = min(span.last, sorted(later)[1]) if len(later) > 2 else span.last
        cut.append(replace(span, first=low, last=high) if high - low >= 2 else span)
    return cut


def agreed(labels: np.ndarray, rows_of: dict[int, np.ndarray], spans: list[Span],
           found: dict[tuple[int, int], alignment.Pairing], n_classes: int) -> np.ndarray:
    """Each boundary moved, between its two clicks, to where most frames agree with the labels the other recordings
    pair with them (their own label counts once, each other recording's vote once)."""
    votes = {u: np.eye(n_classes)[labels[rows]] for u, rows in rows_of.items()}
    for (ours, theirs), pairing in found.items():
        votes[ours] = votes[ours] + pairing.votes(labels[rows_of[theirs]], n_classes)
    return moved_to_votes(labels, rows_of, spans, votes)


def moved_to_votes(labels: np.ndarray, rows_of: dict[int, np.ndarray], spans: list[Span],
                   votes: dict[int, np.ndarray]) -> np.ndarray:
    """Each boundary placed, between its two clicks, where most frames agree with their ``votes`` [frames, C]."""
    moved = labels.copy()
    for s in spans:
        within = votes[s.episode][s.first:s.last + 1]
        earlier, later = np.cumsum(within[:, s.before]), np.cumsum(within[::-1, s.after])[::-1]
        t = int(np.argmax(earlier[:-1] + later[1:])) + 1  # the first frame of ``after``, in 1 .. last - first
        rows = rows_of[s.episode]
        moved[rows[s.first:s.first + t]], moved[rows[s.first + t:s.last + 1]] = s.before, s.after
    return moved


def fill(frames: pl.DataFrame, clicks: list[list[int]], features: list[str]) -> tuple[pl.DataFrame, dict]:
    """frames.parquet with every boundary between two clicks placed, and a record of how: by the training recordings
    labelled on every frame where there are any (their votes, aligned in time to each clicked recording, placing each
    boundary between its two clicks), else from the clicked recordings alone (``from_clicks``)."""
    z = alignment.standardised(frames, features)
    labels = frames["label"].fill_null(-1).to_numpy().astype(np.int64)
    episodes, frame = frames["episode"].to_numpy(), frames["frame"].to_numpy()
    every = alignment.rows_by_recording(episodes)
    rows_of = {e: every[e] for e in clicked_episodes(clicks)}
    spans = [replace(s, first=int(first), last=int(last)) for s in free_spans(clicks)  # frames to positions
             for first, last in [np.searchsorted(frame[rows_of[s.episode]], [s.first, s.last])]]
    record = {"clicks": len(clicks), "boundaries": len(spans)}
    known = alignment.training_recordings(frames, leaving_out=rows_of)  # labelled on every frame, not by clicks
    n_classes = int(labels.max()) + 1
    votes, check = (alignment.aligned_votes(z, list(rows_of.values()), known, labels, n_classes) if known else
                    (None, None))  # None: none labelled on every frame, or they fail alignment's check
    found = alignment.pairings(z, rows_of) if votes is None and len(rows_of) > 1 else {}
    if votes is not None:  # each boundary where the labelled ones, aligned to the clicked one, agree most
        plural = "s" if len(known) != 1 else ""
        placed = moved_to_votes(labels, rows_of, spans, dict(zip(rows_of, votes)))
        return _relabelled(frames, placed), {**record, "labelled": len(known), "checked": check, "method": (
            f"each clicked recording aligned in time to the {len(known)} training recording{plural} labelled on every "
            "frame, within its clicks")}
    placed = from_clicks(z, labels, episodes, rows_of, spans, n_classes, found)
    return _relabelled(frames, placed), {**record, "method": (
        "change point of the standardised features between two clicks, within the other recordings' clicks aligned "
        "to it, aligned with the boundaries of its kind in the other recordings, then agreed with their labels "
        "aligned to it")}


def filled_said(record: dict) -> str:
    """What ``fill`` did (its record, frames.parquet's ``clicks_filled``) in one line, for collect's summary."""
    return (f"clicks: {counted(record['clicks'], 'click')}, one label each; "
            f"{counted(record['boundaries'], 'boundary', 'boundaries')} between them learned ({record['method']}); "
            "clicked recordings all train (their labels between clicks are estimates, never a test split's)")


def from_clicks(z: np.ndarray, labels: np.ndarray, episodes: np.ndarray, rows_of: dict[int, np.ndarray],
                spans: list[Span], n_classes: int, found: dict[tuple[int, int], alignment.Pairing]) -> np.ndarray:
    """The labels with each boundary placed from the clicked recordings alone, ``found`` each aligned to others
    (``alignment.pairings``): change point in the span the other recordings' clicks leave (``narrowed``),
    ``moved_to_their_kind``, then ``agreed``."""
    labels = labels.copy()
    placed = _stretches(rows_of, narrowed(spans, found))
    cuts = moved_to_their_kind(z, episodes, placed, [change_point(z[rows]) for rows, _, _ in placed])
    for (rows, before, after), t in zip(placed, cuts):
        labels[rows[:t]], labels[rows[t:]] = before, after
    return agreed(labels, rows_of, spans, found, n_classes) if found else labels
