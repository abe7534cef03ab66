"""Self-training over the chain: the MLN's formulas and the network label the unlabelled frames for each other.

A frame of an unlabelled recording is learned from only where both say the same class, each with probability
``threshold`` or more. The threshold is chosen by cross-validation on the labelled folds, never on a test split:
on the training rows' out-of-fold probabilities (each fold's network and MLN fitted without it), the lowest
threshold of ``THRESHOLDS`` at which the frames so chosen are ``PRECISION`` right; none when no threshold is.
The frames chosen become intervals (``episode,start,end,label`` in frames) that ``--labels`` reads beside the
labelled recordings' own: the frames left out are dropped, so that a refit learns from what both hold alone."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.methods import PaperFloor

PRECISION = 0.98  # the share of out-of-fold frames chosen that must be right
THRESHOLDS = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99)
MIN_RUN = 10  # frames: a shorter run of agreed frames is left out (a sliver says little of a phase)


@dataclass(frozen=True)
class Agreement:
    """The threshold chosen (None: none reaches PRECISION), and the out-of-fold precision and coverage at it."""

    threshold: float | None
    precision: float
    coverage: float
    folds: bool = True  # False: the workdir has no folds to choose on

    def said(self) -> str:
        if not self.folds:
            return "no folds to choose a threshold on: unlabelled recordings not learned from"
        if self.threshold is None:
            return (f"no threshold makes the network and the MLN agree {PRECISION:.0%} right out of fold: "
                    "unlabelled recordings not learned from")
        return (f"network and MLN agreeing, each at probability {self.threshold:g} or more: {self.precision:.1%} "
                f"right on {self.coverage:.0%} of the labelled frames, out of fold")


def agreed(network_log_probs: np.ndarray, mln_log_probs: np.ndarray, threshold: float) -> tuple[np.ndarray,
                                                                                                   np.ndarray]:
    """Per frame the network's class and whether the MLN says the same, each at ``threshold`` or more."""
    network, mln = network_log_probs.argmax(axis=1), mln_log_probs.argmax(axis=1)
    sure = np.log(threshold)
    confident = (network == mln) & (network_log_probs.max(axis=1) >= sure) & (mln_log_probs.max(axis=1) >= sure)
    return network, confident


def choose_threshold(network_log_probs: np.ndarray, mln_log_probs: np.ndarray, labels: np.ndarray,
                     precision: float = PRECISION) -> Agreement:
    """The lowest threshold whose agreed frames are ``precision`` right, on out-of-fold probabilities."""
    for threshold in THRESHOLDS:
        classes, confident = agreed(network_log_probs, mln_log_probs, threshold)
        if confident.any():
            right = float(np.mean(classes[confident] == labels[confident]))
            if right >= precision:
                return Agreement(threshold, right, float(confident.mean()))
    return Agreement(None, 0.0, 0.0)


def chosen(workdir: Path) -> Agreement:
    """The threshold of a fitted workdir, chosen on its out-of-fold probabilities; none without folds."""
    if not (Path(workdir) / artifacts.FOLD_WEIGHTS).exists():
        return Agreement(None, 0.0, 0.0, folds=False)
    return choose_threshold(*out_of_fold(workdir))


def out_of_fold(workdir: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A fitted workdir's training rows: the network's out-of-fold log-probabilities (models/lstm.oof.parquet), the
    MLN's (each fold's weights and predicates), and the labels; every array over the same rows."""
    from mlnseq.choosing import folds as folding
    from mlnseq.mln.classifier import class_log_probs

    workdir = Path(workdir)
    frames, meta = artifacts.read_table(workdir / artifacts.FRAMES, "frames")
    frames = artifacts.labelled(frames)
    k = int(artifacts.read_metadata(workdir / artifacts.FOLD_WEIGHTS, "fold_weights")["folds"]["k"])
    episodes, splits, labels = (frames[c].to_numpy() for c in ("episode", "split", "label"))
    folds = folding.assign(episodes, splits, labels, k)
    scores, _ = folding.fold_mln_scores(workdir, folds, meta["classes"])
    predictions = artifacts.read_metadata(workdir / artifacts.PREDICTIONS, "predictions")
    mode, floor = predictions.get("mln_mode", "paper"), PaperFloor(predictions.get("paper_floor", "clamp"))
    mln = np.zeros((frames.height, len(meta["classes"])))
    for fold, fold_scores in enumerate(scores):
        rows = folds.fold == fold
        mln[rows] = class_log_probs(fold_scores[rows], mode, floor)
    oof = pl.read_parquet(artifacts.out_of_fold_path(workdir, "lstm"))
    keyed = frames.select("episode", "frame").with_row_index("row").join(oof, on=["episode", "frame"])
    rows = keyed["row"].to_numpy()
    network = keyed.select(artifacts.log_prob_columns(len(meta["classes"]))).to_numpy().astype(np.float64)
    return network, mln[rows], labels[rows].astype(np.int64)


def runs_as_intervals(episode: str, classes: np.ndarray, confident: np.ndarray, names: list[str],
                      min_run: int = MIN_RUN) -> list[tuple[str, int, int, str]]:
    """One recording's runs of agreed frames of one class, MIN_RUN frames or longer, as (episode, first frame,
    last frame, class name): intervals in frames."""
    from mlnseq.timeline import sequences

    key = np.where(confident, classes, -1)
    return [(episode, run.start, run.stop - 1, names[int(key[run.start])]) for run in sequences.runs(key)
            if key[run.start] >= 0 and run.stop - run.start >= min_run]
