"""Candidate predicates learned from a training split, one or two per channel, their thresholds chosen to separate
the classes (decision stumps by information gain), and their out-of-fold gain for ranking them.

Per channel (a feature, or the distance between two 3-D points):

- a **level** (``bins``): up to ``MAX_CUTS`` cuts, each the one that most raises the information gain of the class
  given the bin, added while it raises it by ``MIN_CUT_GAIN`` nats per frame;
- a **change** over a window at the scale the channel moves (``change`` with ``window``): for each window of
  ``WINDOWS`` the dead band of best information gain among quantiles of the channel's change over that window;
- for a gripper's opening instead (``suggest.looks_like_gripper``), a **gripper** predicate: open near its full
  opening, closed below the cut of best gain under it, and between them opening or closing beyond a dead band
  below the gripper's motion per frame (a fraction of its fastest frames' motion, the fraction of best gain).

Cuts are tried at ``QUANTILES`` quantiles of the training values, and every cut, dead band or window is scored from
one histogram of the frames over the cuts tried (class counts per bin, summed up to each cut), so a candidate costs a
few passes over the frames whatever their number and however many cuts are tried; the gains are those of coding every
frame with each cut in turn, to the bit. Codes are one byte a frame. ``oof_gain`` scores a candidate's codes by
cross-validation: the class given its value, counted on the other folds, as log-likelihood of the held-out fold's
classes above the classes' prior.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from mlnseq.choosing.folds import masks
from mlnseq.predicates.rules import looked_back
from mlnseq.predicates.spec import Bins, Change, Gripper

MAX_CUTS = 2
MIN_CUT_GAIN = 0.02  # nats per frame a further cut must add
QUANTILES = 48  # cut points tried per channel
WINDOWS = (1, 2, 4, 8, 16)  # frames a change is measured over
DEAD_BANDS = (0.02, 0.05, 0.1, 0.2, 0.35)  # a gripper's dead band, as a fraction of its fastest motion per frame
LAPLACE = 1.0  # added to every count of the out-of-fold tables
NEAR_BEST = 0.98  # a change whose gain is at least this share of the best one's is as good (the steadiest is kept)


@dataclass(frozen=True)
class Frames:
    """The training split as the candidates see it: every frame (episodes in order), which train, their classes,
    each episode's first frame and the folds (-1 outside the training split)."""

    train: np.ndarray  # bool [n]: fold >= 0
    labels: np.ndarray  # [n] class index
    first: np.ndarray  # bool [n]
    fold: np.ndarray  # [n]
    n_classes: int


@dataclass(frozen=True)
class Candidate:
    """A predicate as a spec writes it, the channel it reads, its kind (level, change, gripper), its code on
    every frame, and its in-sample and out-of-fold gains (nats per training frame); ``by_fold``: the same kind on
    the same channel learned again without each fold (None where it finds nothing there), so that what the
    thresholds learn is cross-validated with them."""

    predicate: Bins | Change | Gripper
    channel: str
    kind: str
    codes: np.ndarray
    gain: float
    oof: float = 0.0
    by_fold: tuple[Candidate | None, ...] = ()

    def fold_codes(self, k: int | None) -> tuple[np.ndarray, int]:
        """The codes on every frame and the number of values: learned without fold ``k`` (None: on the whole
        training split); a fold where the kind found nothing: one value."""
        found = self if k is None else self.by_fold[k]
        return (found.codes, len(found.predicate.values)) if found is not None else (np.zeros_like(self.codes), 1)

    def __eq__(self, other: object) -> bool:
        return self is other

    def __hash__(self) -> int:
        return id(self)


def written(value: float) -> float:
    """A threshold as the spec writes it (six significant digits), so that the spec read back cuts the same frames."""
    return float(f"{float(value):.6g}")


def learned(make, name: str, channel: str, values: np.ndarray, frames: Frames) -> Candidate | None:
    """``make`` (level, change, gripper) on the training split, with its out-of-fold gain and itself learned again
    without each fold."""
    found = make(name, channel, values, frames)
    if found is None:
        return None
    folds = masks(frames.fold)
    by_fold = tuple(make(name, channel, values, replace(frames, train=fold.fit)) for fold in folds)
    found = replace(found, by_fold=by_fold)
    return replace(found, oof=oof_gain(found, frames)) if folds else found


def entropy(counts: np.ndarray) -> np.ndarray:
    """Per row of class counts [..., C]: its entropy (nats) times its total."""
    total = counts.sum(axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(counts > 0, counts / np.where(total > 0, total, 1), 1.0)
    return -(counts * np.log(share)).sum(axis=-1)


def gain_of(codes: np.ndarray, frames: Frames) -> float:
    """In-sample information gain of the class given ``codes`` on the training frames, nats per frame."""
    labels, codes = frames.labels[frames.train], codes[frames.train].astype(np.int64)
    n_values = int(codes.max()) + 1 if codes.size else 1
    table = np.bincount(codes * frames.n_classes + labels, minlength=n_values * frames.n_classes)
    return gains_of(table.reshape(1, n_values, frames.n_classes).astype(np.float64), len(labels))[0]


def gains_of(tables: np.ndarray, frames: int) -> np.ndarray:
    """[J] the information gain (nats per frame) of each coding's class table [J, values, C] of ``frames`` frames
    (rows of values no frame takes add nothing)."""
    return (entropy(tables[0].sum(axis=0)) - entropy(tables).sum(axis=1)) / max(frames, 1)


def class_counts(index: np.ndarray, labels: np.ndarray, size: int, n_classes: int) -> np.ndarray:
    """[size, C] the frames of each ``index`` (0 .. size - 1) counted per class, as floats."""
    counts = np.bincount(index.astype(np.int64) * n_classes + labels, minlength=size * n_classes)
    return counts.reshape(size, n_classes).astype(np.float64)


def oof_gain(candidate: Candidate, frames: Frames) -> float:
    """Out-of-fold gain: each fold's classes given the candidate learned without it, by the other folds' counts
    (Laplace), as log-likelihood above the other folds' class prior, nats per training frame."""
    total, count = 0.0, 0
    for k, fold in enumerate(masks(frames.fold)):
        codes, n_values = candidate.fold_codes(k)
        fit, held = fold.fit, fold.held
        table = class_counts(codes[fit], frames.labels[fit], n_values, frames.n_classes) + LAPLACE
        given = np.log(table / table.sum(axis=1, keepdims=True))
        prior = np.log(table.sum(axis=0) / table.sum())
        total += float((given[codes[held], frames.labels[held]] - prior[frames.labels[held]]).sum())
        count += int(held.sum())
    return total / max(count, 1)


def cut_points(values: np.ndarray) -> np.ndarray:
    """Distinct candidate cuts: midpoints between the training values' quantiles."""
    levels = np.unique(np.quantile(values, np.linspace(0, 1, QUANTILES + 2)))
    return (levels[:-1] + levels[1:]) / 2


def stumps(values: np.ndarray, frames: Frames, most: int = MAX_CUTS) -> tuple[list[float], float]:
    """Cuts added one at a time, each the one of best information gain, while a cut adds ``MIN_CUT_GAIN``."""
    x, labels = values[frames.train], frames.labels[frames.train]
    tried = cut_points(x)
    if not tried.size:
        return [], 0.0
    # row r + 1: the values between cuts r - 1 and r
    rows = class_counts(np.searchsorted(tried, x, side="left") + 1, labels, len(tried) + 2, frames.n_classes)
    below = np.cumsum(rows, axis=0)  # [r]: the class counts of the values below cut r - 1 (row 0: none)
    chosen: list[int] = []  # rows: cut r - 1
    gained = 0.0
    while len(chosen) < most:
        bounds = [0, *sorted(chosen), len(tried) + 1]
        best, best_gain = 0, 0.0
        for low, high in zip(bounds, bounds[1:]):
            split = np.arange(low + 1, high)
            if not split.size:
                continue
            inside, left = below[high] - below[low], below[split] - below[low]
            gains = (entropy(inside) - entropy(left) - entropy(inside - left)) / len(x)
            k = int(np.argmax(gains))
            if gains[k] > best_gain:
                best, best_gain = int(split[k]), float(gains[k])
        if best_gain < MIN_CUT_GAIN:
            break
        chosen.append(best)
        gained += best_gain
    return sorted({written(tried[r - 1]) for r in chosen}), gained


LEVEL_NAMES = {1: ("low", "high"), 2: ("low", "mid", "high")}


def level(name: str, channel: str, values: np.ndarray, frames: Frames) -> Candidate | None:
    cuts, gained = stumps(values, frames)
    if not cuts:
        return None
    predicate = Bins(name, channel, tuple(cuts), LEVEL_NAMES[len(cuts)])
    codes = np.searchsorted(np.asarray(cuts), values, side="right").astype(CODE)
    return Candidate(predicate, channel, "level", codes, gained)


CODE = np.uint8  # a frame's value of a candidate: at most a few


def change_codes(delta: np.ndarray, threshold: float) -> np.ndarray:
    return np.where(delta > threshold, 1, np.where(delta < -threshold, 2, 0)).astype(CODE)


def change_gains(delta: np.ndarray, thresholds: np.ndarray, frames: Frames) -> np.ndarray:
    """[J] the gain of ``change_codes`` at each of the ascending ``thresholds`` (>= 0) on the training frames: each
    frame's rise (fall) binned by the thresholds it exceeds, the bins summed from the top."""
    moved, labels, c = delta[frames.train], frames.labels[frames.train], frames.n_classes
    size = len(thresholds) + 1
    rises = class_counts(np.where(moved > 0, np.searchsorted(thresholds, moved, side="left"), 0), labels, size, c)
    falls = class_counts(np.where(moved < 0, np.searchsorted(thresholds, -moved, side="left"), 0), labels, size, c)
    above = np.cumsum(rises[::-1], axis=0)[::-1][1:]  # [j]: frames rising beyond threshold j
    below = np.cumsum(falls[::-1], axis=0)[::-1][1:]
    total = rises.sum(axis=0)
    return gains_of(np.stack([total - above - below, above, below], axis=1), len(labels))


def change(name: str, channel: str, values: np.ndarray, frames: Frames) -> Candidate | None:
    """The window and dead band of best information gain; among those within ``NEAR_BEST`` of it, the shortest
    window and its middle dead band (a choice that moves little with the frames it is learned on)."""
    tried: list[tuple[int, float, float]] = []  # window, threshold, gain
    for window in WINDOWS:
        delta = values - looked_back(values, frames.first, window)
        delta[frames.first] = 0.0
        moved = np.abs(delta[frames.train])
        thresholds = np.unique([written(q) for q in np.quantile(moved, np.linspace(0.1, 0.9, 9))])
        tried += zip([window] * len(thresholds), thresholds.tolist(), change_gains(delta, thresholds, frames).tolist())
    chosen = steady(tried, lambda t: t[0], lambda t: t[1], lambda t: t[2])
    if chosen is None:
        return None
    window, threshold, gained = chosen
    delta = values - looked_back(values, frames.first, window)
    delta[frames.first] = 0.0
    return Candidate(Change(name, channel, threshold, window=window), channel, "change",
                     change_codes(delta, threshold), gained)


def steady(tried: list, first, second, gain=lambda c: c.gain):
    """Among the candidates within NEAR_BEST of the best ``gain``: the least ``first``, then the middle ``second``."""
    best = max((gain(c) for c in tried), default=0.0)
    if best <= 0:
        return None
    near = [c for c in tried if gain(c) >= NEAR_BEST * best]
    least = min(first(c) for c in near)
    near = sorted((c for c in near if first(c) == least), key=second)
    return near[len(near) // 2]


def gripper_codes(values: np.ndarray, delta: np.ndarray, open_above: float, closed_below: float,
                  threshold: float) -> np.ndarray:
    return np.select([values > open_above, values < closed_below, delta > threshold, delta < -threshold],
                     [0, 1, 2, 3], 4).astype(CODE)


def closed_gains(values: np.ndarray, delta: np.ndarray, open_above: float, closed: np.ndarray, threshold: float,
                 frames: Frames) -> np.ndarray:
    """[J] the gain of ``gripper_codes`` with each of the ascending ``closed`` cuts on the training frames: the frames
    not open binned by the cuts above them, closed below a cut, else coded by their motion."""
    x, moved, labels, c = values[frames.train], delta[frames.train], frames.labels[frames.train], frames.n_classes
    shut = x <= open_above
    motion = np.select([moved > threshold, moved < -threshold], [0, 1], 2)  # opening, closing, still
    size = len(closed) + 1
    binned = class_counts(np.searchsorted(closed, x[shut], side="right") * 3 + motion[shut], labels[shut], size * 3, c)
    binned = binned.reshape(size, 3, c)
    below = np.cumsum(binned.sum(axis=1), axis=0)[:-1]  # [j]: frames under cut j
    moving = np.cumsum(binned[::-1], axis=0)[::-1][1:]  # [j, motion]: frames at or above cut j
    opened = class_counts(np.zeros((~shut).sum(), dtype=np.int64), labels[~shut], 1, c)
    tables = np.concatenate([np.broadcast_to(opened, (len(closed), 1, c)), below[:, None], moving], axis=1)
    return gains_of(tables, len(labels))


def gripper(name: str, channel: str, values: np.ndarray, frames: Frames) -> Candidate | None:
    """Open within a tenth of its range of its full opening; closed below the cut of best gain under that; opening
    and closing beyond the dead band of best gain, a fraction of its fastest motion per frame."""
    train = values[frames.train]
    low, high = np.quantile(train, [0.02, 0.98])
    if not high > low:
        return None
    open_above = written(high - 0.1 * (high - low))
    delta = values - looked_back(values, frames.first, 1)
    delta[frames.first] = 0.0
    fastest = float(np.quantile(np.abs(delta[frames.train]), 0.99))
    below = train[train < open_above]
    tried = cut_points(below) if below.size > 1 else np.array([open_above])

    def scored(closed_below: float, share: float) -> Candidate:
        predicate = Gripper(name, channel, open_above, closed_below, written(share * fastest))
        codes = gripper_codes(values, delta, predicate.open_above, predicate.closed_below, predicate.threshold)
        return Candidate(predicate, channel, "gripper", codes, gain_of(codes, frames))

    cuts = np.array([written(min(c, open_above)) for c in tried])
    closed = float(cuts[np.argmax(closed_gains(values, delta, open_above, cuts, written(0.1 * fastest), frames))])
    return max((scored(closed, share) for share in DEAD_BANDS), key=lambda c: c.gain)
