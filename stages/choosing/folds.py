"""Folds of the training split for cross-validation: whole episodes when the split has at least K of them,
else K contiguous blocks of its frames (in file order), cut where the labels show the task restarting (an episode
starts, or the labels return to the class episodes start with) nearest to K equal blocks' cuts, else at the
nearest segment boundaries, never inside a segment where the split has enough of them. The assignment depends
only on the frames' episodes, splits, labels and on K, so train (the fold networks), learn-weights (each fold's
MLN weights) and conflate (the out-of-fold decoding) cut the same folds; every artifact made from them records
them. A fold is its fit rows (the other folds') and its held-out rows (``masks``): every cross-validation, conflate's
and the logic learner's, loops over these."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.parts import Part
from mlnseq.mln.chain import chain_starts

MIN_BLOCK_FRAMES = 20  # a block fold holds at least this many frames: shorter chains say little
MOST_FOLDS = 5  # the folds suggested (fit's default): one per training episode, at most this many


CUTS = ("restarts", "mixed", "segments", "frames")  # where blocks were cut: task restarts, restarts and segment
# ends, segment ends only, or anywhere (a training split with too few segments)


@dataclass(frozen=True)
class Folds:
    fold: np.ndarray  # [n] fold of each training row, -1 on test rows
    kind: str  # episodes | blocks
    cut: str | None = None  # blocks: one of CUTS

    @property
    def k(self) -> int:
        return int(self.fold.max()) + 1

    def record(self) -> dict:
        """The assignment as metadata: K, the kind and each fold's row spans."""
        from mlnseq.timeline import sequences

        spans = [[s.start, s.stop] for s in sequences.runs(self.fold) if self.fold[s.start] >= 0]
        return {"k": self.k, "kind": self.kind, "spans": spans, **({"cut": self.cut} if self.cut else {})}

    def describe(self) -> str:
        """What was cut, for summaries: ``4 folds by episode`` or ``5 folds by block``."""
        return describe(self.record())

    def masks(self) -> list[Fold]:
        """Each fold's fit and held-out rows (:func:`masks`)."""
        return masks(self.fold)

    def splits(self, k: int) -> np.ndarray:
        """The splits with fold ``k``'s rows marked ``heldout``: what a fold's network and MLN are fitted without."""
        return np.where(self.fold == k, Part.HELDOUT, np.where(self.fold >= 0, Part.TRAIN, Part.TEST))


@dataclass(frozen=True)
class Fold:
    """One fold of the training split: the rows its model is fitted on (the other folds') and the rows it is held
    out on (its own)."""

    fit: np.ndarray  # bool [n]
    held: np.ndarray  # bool [n]

    @property
    def rows(self) -> np.ndarray:
        """The held-out rows' indices."""
        return np.flatnonzero(self.held)

    def starts(self, episodes: np.ndarray) -> np.ndarray:
        """bool [held-out rows]: where their chains start (an episode, or where the fold resumes)."""
        return chain_starts(episodes, rows=self.rows)

    def start(self, labels: np.ndarray, episodes: np.ndarray, n_classes: int) -> np.ndarray:
        """The start distribution (log [C]) fitted on the fit rows."""
        from mlnseq.fusion.decoding import start_of

        return start_of(labels, episodes, self.fit, n_classes)


def masks(fold: np.ndarray) -> list[Fold]:
    """Each fold of ``fold`` (every row's fold, -1 outside the training split) in order: its fit rows (the other
    folds') and its held-out rows. The one way a fold is made: every cross-validation loops over these."""
    fold = np.asarray(fold)
    return [Fold((fold >= 0) & (fold != k), fold == k) for k in range(int(fold.max()) + 1)]


CUT_WORDS = {"restarts": " at task restarts", "mixed": " at task restarts and segment ends",
             "segments": " at segment ends", "frames": " inside segments"}


def describe(record: dict) -> str:
    """A recorded assignment (Folds.record) in words: ``4 folds by episode``, ``5 folds by block at task
    restarts`` (``at segment ends``, ``inside segments``)."""
    if record["kind"] == "episodes":
        return f"{record['k']} folds by episode"
    return f"{record['k']} folds by block{CUT_WORDS.get(record.get('cut'), '')}"


def largest(episodes: np.ndarray, splits: np.ndarray) -> int:
    """The largest K the training split allows: its episodes, or its blocks of MIN_BLOCK_FRAMES frames."""
    train = np.asarray(splits) == Part.TRAIN
    return max(len(np.unique(np.asarray(episodes)[train])), int(train.sum()) // MIN_BLOCK_FRAMES)


def suggested(episodes: np.ndarray, splits: np.ndarray, most: int = MOST_FOLDS,
              labels: np.ndarray | None = None) -> int:
    """A K for a user's recogniser: whole episodes when the training split has at least 2 (up to ``most`` folds),
    else blocks (up to ``most``), else 0 (too small for folds). Given the ``labels``, blocks only where they can be
    cut where the task restarts: a single recording of one run of the task cut into blocks holds whole phases out of
    each fold's training, and cross-validation on it chooses worse than none."""
    train = np.asarray(splits) == "train"
    n_episodes = len(np.unique(np.asarray(episodes)[train]))
    if n_episodes >= 2:
        return min(most, n_episodes)
    k = min(most, largest(episodes, splits))
    if k >= 2 and labels is not None and assign(episodes, splits, labels, k).cut != "restarts":
        return 0
    return k if k >= 2 else 0


def assign(episodes: np.ndarray, splits: np.ndarray, labels: np.ndarray, k: int, option: str = "--folds") -> Folds:
    """Cut the training rows into ``k`` folds (deterministic); refuse a K the split cannot make."""
    episodes, train = np.asarray(episodes), np.asarray(splits) == Part.TRAIN
    most = largest(episodes, splits)
    if k < 2 or k > most:
        good = suggested(episodes, splits)
        n_episodes = len(np.unique(episodes[train]))
        raise BadInput(f"{option} {k}: cross-validation needs at least 2 folds and this training split allows at "
                       f"most {most}; use {option} {good} ({good} folds by "
                       f"{'episode' if n_episodes >= good else 'block'}, as `mlnseq fit` cuts)" if most >= 2 else
                       f"{option} {k}: this training split is too small for 2 folds; use {option} 0")
    rows = np.flatnonzero(train)
    fold = np.full(len(episodes), -1, dtype=np.int64)
    present = list(dict.fromkeys(episodes[rows].tolist()))
    if len(present) >= k:
        for index, group in enumerate(np.array_split(np.arange(len(present)), k)):
            fold[rows[np.isin(episodes[rows], [present[i] for i in group])]] = index
        return Folds(fold, "episodes")
    cuts, cut = block_cuts(episodes[rows], np.asarray(labels)[rows], k)
    for index, (start, stop) in enumerate(zip([0, *cuts], [*cuts, len(rows)])):
        fold[rows[start:stop]] = index
    return Folds(fold, "blocks", cut)


def block_cuts(episodes: np.ndarray, labels: np.ndarray, k: int) -> tuple[list[int], str]:
    """Where K blocks of the training rows begin (positions 1 .. n-1, ascending), and how they were cut: the cuts of
    K equal blocks each moved to a task restart, at least cost (the sum of the moves; a segment boundary that is
    not a restart costs half a block more), in order; with too few boundaries, the equal cuts."""
    from mlnseq.fusion.decoding import start_of

    n = len(labels)
    ideal = np.array([round(n * j / k) for j in range(1, k)], dtype=np.float64)
    new_episode = chain_starts(episodes)
    start_class = int(np.argmax(start_of(labels, episodes, np.ones(n, dtype=bool), int(labels.max()) + 1)))
    changed = np.r_[False, labels[1:] != labels[:-1]] | new_episode
    restart = new_episode | (changed & (labels == start_class))
    where = np.flatnonzero(changed[1:]) + 1
    if len(where) < k - 1:
        return [int(c) for c in ideal], "frames"
    extra = np.where(restart[where], 0.0, n / (2 * k))
    chosen = cheapest(where, np.abs(where[None, :] - ideal[:, None]) + extra[None, :])
    at_restarts = restart[where[chosen]]
    return [int(where[i]) for i in chosen], ("restarts" if at_restarts.all() else "mixed" if at_restarts.any()
                                               else "segments")


def cheapest(where: np.ndarray, cost: np.ndarray) -> list[int]:
    """Indices i_1 < ... < i_m into ``where`` of least total ``cost[j, i_j]`` (cost: [m, len(where)]; ties: the
    earliest)."""
    m, size = cost.shape
    total, back = np.full((m, size), np.inf), np.zeros((m, size), dtype=np.int64)
    total[0] = cost[0]
    for j in range(1, m):
        before = total[j - 1]
        least = np.minimum.accumulate(before)
        new = before < np.r_[np.inf, least[:-1]]
        back[j, 1:] = np.maximum.accumulate(np.where(new, np.arange(size), 0))[:-1]
        total[j, 1:] = least[:-1] + cost[j, 1:]
    chosen = [int(np.argmin(total[-1]))]
    for j in range(m - 1, 0, -1):
        chosen.append(int(back[j, chosen[-1]]))
    return chosen[::-1]


def train_folds(k: int | None, mode: str, select: str, workdir: Path | None = None) -> int | None:
    """``train --folds``'s K: as asked; None, the default: in stream mode without a validation part, the K of the
    folds the MLN's weights were learned on (weights.folds.parquet, from `learn-weights --folds K`), else none
    (None); 0 is none."""
    if k is not None:
        return k
    path = None if workdir is None else Path(workdir) / artifacts.FOLD_WEIGHTS
    if mode != "stream" or select != "none" or path is None or not path.exists():
        return None
    return int(artifacts.read_metadata(path, "fold_weights")["folds"]["k"])


def resolve(k: int | None, mode: str, select: str, episodes: np.ndarray, splits: np.ndarray, labels: np.ndarray,
            workdir: Path | None = None) -> Folds | None:
    """``train --folds``: the folds of ``train_folds``' K, or None (none)."""
    k = train_folds(k, mode, select, workdir)
    return assign(episodes, splits, labels, k) if k else None


def out_of_fold_said(checkpoint: Path, asked: bool) -> str:
    """A trained network's fold networks in words (train's summary): which folds, where they came from (asked, or as
    learn-weights cut them) and the out-of-fold predictions; "" without."""
    oof = artifacts.out_of_fold_path(Path(checkpoint).parent.parent, Path(checkpoint).stem)
    if not oof.exists():
        return ""
    how = "" if asked else f", as learn-weights cut them ({artifacts.FOLD_WEIGHTS})"
    return f"; with {describe(artifacts.read_metadata(oof)['folds'])}{how}: out-of-fold predictions {oof}"


def same(recorded: dict, folds: Folds, what: str, remedy: str) -> None:
    """Refuse an artifact whose recorded folds differ from ``folds``."""
    if recorded != folds.record():
        raise BadInput(f"{what} was made with other folds ({recorded.get('k')} {recorded.get('kind')}) than "
                       f"{folds.k} {folds.kind}; rerun {remedy}")


def missing_classes(folds: Folds, labels: np.ndarray, classes: list[str]) -> list[str]:
    """A warning per fold whose fit part lacks a class the training split has."""
    train = folds.fold >= 0
    warnings = []
    for k, fold in enumerate(folds.masks()):
        missing = sorted(set(labels[train].tolist()) - set(labels[fold.fit].tolist()))
        if missing:
            warnings.append(f"fold {k}: its fit part lacks class{'es' if len(missing) > 1 else ''} "
                            f"{', '.join(classes[c] for c in missing)}; its out-of-fold predictions are written "
                            "all the same")
    return warnings


def out_of_fold_table(keys: pl.DataFrame, folds: Folds, log_probs: np.ndarray) -> pl.DataFrame:
    """The training rows' keys (episode, frame), fold and out-of-fold class log-probabilities (lp0..)."""
    rows = folds.fold >= 0
    table = keys.filter(pl.Series(rows)).with_columns(pl.Series("fold", folds.fold[rows], dtype=pl.Int16))
    return table.with_columns([pl.Series(name, log_probs[rows, c], dtype=pl.Float32)
                               for c, name in enumerate(artifacts.log_prob_columns(log_probs.shape[1]))])


def fold_mln_scores(workdir: Path, folds: Folds, classes: Sequence[str]) -> tuple[list[np.ndarray], list[Path]]:
    """Each fold's per-frame MLN class scores, from weights.folds.parquet (checked to hold the same folds) and each
    fold's predicates (:func:`fold_predicates`)."""
    from mlnseq.mln import classifier

    weights, path = fold_weights(workdir, folds)
    predicates, meta = artifacts.read_table(Path(workdir) / artifacts.PREDICATES, "predicates")
    tables, read = fold_predicates(workdir, folds, predicates, meta)
    return [classifier.class_scores(t, w, classes) for t, w in zip(tables, weights)], [path, *read]


def fold_predicates(workdir: Path, folds: Folds, predicates: pl.DataFrame,
                    meta: dict) -> tuple[list[pl.DataFrame], list[Path]]:
    """Each fold's predicates: where binarize --suggest learned them (predicates.folds.parquet, of these folds and
    this spec), the learned predicates learned again without the fold, so that what their thresholds learn is
    cross-validated too; else the workdir's predicates for every fold (a spec that nothing learned). And the file
    read, if any."""
    path = Path(workdir) / artifacts.FOLD_PREDICATES
    if path.exists():
        table, made = artifacts.read_table(path, "fold_predicates")
        if made.get("folds") == folds.record() and made.get("spec_text") == meta.get("spec", {}).get("text"):
            return [table.filter(pl.col("fold") == k).drop("fold") for k in range(folds.k)], [path]
    return [predicates] * folds.k, []


def fold_weights(workdir: Path, folds: Folds) -> tuple[list[pl.DataFrame], Path]:
    """Each fold's MLN weights table (weights.folds.parquet), refused when made with other folds."""
    path = Path(workdir) / artifacts.FOLD_WEIGHTS
    if not path.exists():
        raise BadInput(f"{path} not found: cross-validation reads each fold's MLN weights; run "
                       f"`mlnseq learn-weights --folds {folds.k}` first (or train with --folds 0)")
    table, meta = artifacts.read_table(path, "fold_weights")
    same(meta["folds"], folds, str(path), f"`mlnseq learn-weights --folds {folds.k}`")
    return [table.filter(pl.col("fold") == k).drop("fold") for k in range(folds.k)], path
