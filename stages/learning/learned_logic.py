"""Predicates and formulas learned from the training split, chosen by cross-validation on the folds `mlnseq fit`
cuts (`binarize --suggest` and `fit` without --spec).

1. **Candidates** (mlnseq.learning.candidates): per channel (each feature, and the distance between two 3-D
   points) a level and a change over a window, or a gripper predicate, their thresholds by decision stumps.
2. **A pool**: of the ``PRESELECT`` candidates of best out-of-fold gain (and every gripper), the ``POOL`` whose
   chain alone scores best in the quick stand-in below, at most ``PER_CHANNEL`` per channel (bounded cost on a
   hundred channels: a few passes over the frames per candidate, then ``PRESELECT`` quick scores).
3. **Forward selection**: at each step the ``VERIFIED`` candidates (or all grippers at once) of best score in a
   quick stand-in for the chain's cross-validation (learning/quick_chain.py) are scored exactly: the MLN of the
   per-frame template and learned transitions, its weights learned by the chain's exact likelihood on each fold's
   other folds (as `learn-weights --folds`), each held-out fold decoded by the filter and the lag-0 Viterbi (as
   conflate's cross-validation of mln+filter; the better counts); the best is added while it raises the
   cross-validated frame accuracy by ``MIN_STEP`` points, up to ``MAX_PREDICATES``.
4. Every candidate's thresholds are learned again without each fold, and each fold is scored with its own: what
   the thresholds learn is cross-validated with them.
5. **Conjunctions**: for the ``PAIRS`` pairs of kept predicates whose values interact most (the per-frame
   log-likelihood of their joint values above that of the two added), a formula per joint value seen in
   ``MIN_SUPPORT`` training frames, ``Has(a) ^ Has(b) => Topic(+c)``, kept where the exact score rises by
   ``MIN_STEP``.

Where the training split holds more than ``SEARCH_FRAMES`` frames, all of the above runs on whole episodes drawn
evenly from each of its folds, that many frames in all (``sampled``): a set's cross-validated score changes by a
fraction of a point between a few dozen episodes and hundreds, while its cost grows with every frame. The folds are
those `mlnseq fit` cuts on the whole split, so each fold's predicates are still learned without its episodes; the
weights the model keeps are learned later on every training frame (`learn-weights`).

Nothing here reads the test split.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import polars as pl

from mlnseq.catalog.parts import Part
from mlnseq.choosing import folds as folding
from mlnseq.mln.chain import chain_starts
from mlnseq.learning import candidates as kinds
from mlnseq.learning.candidates import Candidate, Frames
from mlnseq.predicates.spec import Distance
from mlnseq.learning import quick_chain
from mlnseq.learning.training_frames import SEARCH_FRAMES, Training, training

PRESELECT = 40  # candidates of best out-of-fold gain whose chains are scored (with every gripper)
POOL = 20
PER_CHANNEL = 2
MAX_PREDICATES = 6
VERIFIED = 3  # moves of best quick score scored exactly at each step of the forward selection
MIN_STEP = 0.5  # points of SCORE a further predicate or conjunction must add (chosen by frame accuracy rather
# than the criterion fit chooses methods by: the edit score punishes a few flickering frames the decoders smooth)
SCORE = "frame_accuracy"  # of the MLN, cross-validated, by the better of DECODERS: what a set is chosen by
DECODERS = ("filter", "lagviterbi@0")  # the MLN's decoders at lag 0 a set is scored with: the better one counts
PAIRS = 3
MIN_SUPPORT = 0.01  # share of training frames a conjunction's body must hold in (and at least 10 frames)


Scored = tuple[dict[str, float], list[dict[str, float]]]  # exact figures, and each fold's weights by formula


@dataclass(frozen=True)
class Conjunction:
    """A formula body of two predicate values, its training frames' classes counted."""

    first: str  # columns: predicate_value
    second: str
    classes: np.ndarray  # [C] training frames where both hold, per class


@dataclass
class Searched:
    """What the search tried and found: the predicates kept (in the order added), the conjunctions kept, each set
    of the path with its exact figures, the candidates and channels read, the folds."""

    predicates: list[Candidate]
    conjunctions: list[Conjunction] = field(default_factory=list)
    path: list[dict] = field(default_factory=list)
    candidates: int = 0
    channels: int = 0
    folds: str = ""
    figures: dict[str, float] = field(default_factory=dict)  # the kept set's exact cross-validated figures
    distances: list[Distance] = field(default_factory=list)
    train: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # the frames the weights learn on
    weights: pl.DataFrame | None = None  # the kept formulas' weights learned on the whole training split
    fold_record: dict | None = None  # the folds searched on (Folds.record)
    frames: pl.DataFrame | None = None  # the frames searched (every training frame, or the episodes drawn)
    sampled: tuple[int, int] | None = None  # (episodes searched, training episodes) where the search drew some


def pool(found: list[Candidate], data: Training) -> list[Candidate]:
    """Every gripper (its per-frame gain may mislead: two arms that take turns), and up to POOL in all of the others
    whose chain alone scores best (quick_chain.score), at most PER_CHANNEL of one channel, from the PRESELECT of best
    out-of-fold gain."""
    ranked = sorted(found, key=lambda c: -c.oof)
    tried = [c for c in ranked[:PRESELECT]] + [c for c in ranked[PRESELECT:] if c.kind == "gripper"]
    scored = sorted(tried, key=lambda c: quick_chain.score(fold_evidence([c], data), data.split), reverse=True)
    taken: dict[str, int] = {}
    chosen = [c for c in scored if c.kind == "gripper"]
    for candidate in scored:
        if candidate.kind != "gripper" and taken.get(candidate.channel, 0) < PER_CHANNEL and len(chosen) < POOL:
            taken[candidate.channel] = taken.get(candidate.channel, 0) + 1
            chosen.append(candidate)
    return chosen


def evidence_of(chosen: list[Candidate], frames: int, rows: np.ndarray | slice = slice(None),
                fold: int | None = None) -> np.ndarray:
    """bool [rows of ``frames``, columns]: the one-hot values of ``chosen`` (learned without ``fold``; None: on the
    whole split)."""
    coded = [c.fold_codes(fold) for c in chosen]
    return quick_chain.one_hot([codes[rows] for codes, _ in coded], [n for _, n in coded],
                               len(np.arange(frames)[rows]))


def columns_of(chosen: list[Candidate], fold: int | None = None) -> list[str]:
    """The predicate columns of ``chosen`` as learned without ``fold`` (None: on the whole split)."""
    return [f"{found.predicate.name}_{v}" for c in chosen
            if (found := c if fold is None else c.by_fold[fold]) is not None for v in found.predicate.values]


def fold_evidence(chosen: list[Candidate], data: Training) -> list[np.ndarray]:
    """Per fold, the training rows' evidence of ``chosen`` as learned without that fold."""
    return [evidence_of(chosen, len(data.frames.labels), data.rows, k) for k in range(data.split.k)]


def forward(found: list[Candidate], data: Training) -> list[tuple[list[Candidate], Scored]]:
    """The forward selection's path: at each step the ``VERIFIED`` moves (a candidate, or every gripper not yet chosen
    at once: two arms' grippers say little alone) of best quick score, and the grippers at once, scored exactly; the
    best of them added while it raises the exact SCORE by MIN_STEP; each set on the path with its exact figures and
    each fold's weights."""
    chosen: list[Candidate] = []
    path: list[tuple[list[Candidate], Scored]] = []
    current, near = -np.inf, None
    while len(chosen) < MAX_PREDICATES:
        grippers = [c for c in found if c.kind == "gripper" and c not in chosen]
        moves = [[c] for c in found if c not in chosen] + ([grippers] if len(grippers) > 1 else [])
        quick = sorted(moves, key=lambda m: quick_chain.score(fold_evidence(chosen + m, data), data.split),
                       reverse=True)[:VERIFIED]
        quick += [grippers] if len(grippers) > 1 and grippers not in quick else []
        if not quick:
            break
        (figures, weights), move = max(((exact(chosen + m, [], data, near), m) for m in quick),
                                       key=lambda item: item[0][0][SCORE])
        if figures[SCORE] < current + MIN_STEP:
            break
        chosen = chosen + move
        path.append((chosen, (figures, weights)))
        current, near = figures[SCORE], weights
    return path


Found = list[tuple[str, str, np.ndarray, bool]]  # per channel: its column, predicate name, values, whether derived


def channels(frames: pl.DataFrame) -> tuple[Found, list[Distance]]:
    """(column, predicate name, values, derived) of every feature and of the distance between each pair of the first
    3-D points, and those distances as spec channels."""
    from mlnseq.catalog import artifacts
    from mlnseq.learning import suggest

    features = artifacts.feature_columns(frames)
    names = suggest.names_for(features)
    found = [(c, names[c], frames[c].cast(pl.Float64).to_numpy(), False) for c in features]
    distances = []
    for name, start, end, short in suggest.distance_channels(features, set(frames.columns)):
        points = [np.column_stack([frames[c].cast(pl.Float64).to_numpy() for c in p]) for p in (start, end)]
        distance = np.sqrt(((points[1] - points[0]) ** 2).sum(axis=1))
        found.append((name, suggest.unique(short, set(names.values())), distance, True))
        distances.append(Distance(name, start, end))
    return found, distances


def candidates_of(found: Found, view: Frames) -> list[Candidate]:
    """Each channel's candidates (a gripper, or a level and a change; a distance is no gripper) with their out-of-fold
    gains."""
    from mlnseq.learning import suggest

    taken: set[str] = set()
    made: list[Candidate] = []
    for column, name, values, derived in found:
        train = values[view.train]
        if not np.isfinite(values).all() or not train.size or train.min() == train.max():
            continue
        moves = np.abs(np.diff(train))
        if not derived and suggest.looks_like_gripper(suggest.Channel(column, name, train, moves)):
            tried = [(kinds.gripper, name)]
        else:
            tried = [(kinds.level, name), (kinds.change, f"{name}_change")]
        made += [c for make, named in tried
                 if (c := kinds.learned(make, suggest.unique(named, taken), column, values, view)) is not None]
    return made


def fold_weights(evidence: np.ndarray, labels: np.ndarray, starts: np.ndarray, columns: list[str], mln,
                 n_classes: int, near: dict[str, float] | None = None) -> pl.DataFrame:
    """The formulas' weights learned on these frames as `learn-weights` learns them (cll, its default penalty): a
    table of formula and weight (hard: none). ``near``: weights of formulas learned before (a smaller set's), from
    which the learner starts (the others at 0)."""
    from mlnseq.mln import cll
    from mlnseq.mln.grounding import AtomSpace, class_constant, expand_templates
    from mlnseq.mln.syntax import format_formula

    seen = evidence.any(axis=0)
    words = tuple(c for c, on in zip(columns, seen) if on)
    present = tuple(class_constant(k) for k in sorted(set(labels.tolist())))
    expanded, _, _ = expand_templates(mln.formulas, AtomSpace(words, present))
    texts = [format_formula(e.formula) for e in expanded]
    states = AtomSpace(words, tuple(class_constant(k) for k in range(n_classes)))
    initial = None if near is None else np.array([near.get(t, 0.0) for t in texts])
    weights = cll.learn(expanded, evidence[:, seen], labels, starts, states, l2=cll.DEFAULT_L2, initial=initial)
    return pl.DataFrame({"formula": texts, "weight": weights, "hard": [False] * len(expanded)})


def exact(chosen: list[Candidate], conjunctions: list[Conjunction], data: Training,
          near: list[dict[str, float]] | None = None) -> Scored:
    """The MLN of ``chosen`` (and ``conjunctions``) cross-validated as conflate scores mln+filter: each fold's weights
    learned on the other folds (from ``near``'s, a smaller set's, where given), its frames decoded by the filter from
    the other folds' start distribution. Its figures, and each fold's weights."""
    from mlnseq.mln.factors import MLNFactors
    from mlnseq.choosing.cross_validation import figures_of
    from mlnseq.choosing.latency import criterion
    from mlnseq.fusion.decoding import decode_all
    from mlnseq.fusion.fuse import chain_of

    view, episodes = data.frames, data.episodes
    mln = formulas(conjunctions)
    predicted = {d: np.zeros(len(view.labels), dtype=np.int64) for d in DECODERS}
    learned = []
    for k, fold in enumerate(data.folds.masks()):
        evidence, columns = evidence_of(chosen, len(view.labels), fold=k), columns_of(chosen, k)
        fit, held = fold.fit, fold.rows
        weights = fold_weights(evidence[fit], view.labels[fit], chain_starts(episodes, rows=fit), columns, mln,
                               view.n_classes, None if near is None else near[k])
        learned.append(dict(weights.select("formula", "weight").iter_rows()))
        factors = MLNFactors.from_weights(weights, columns, view.n_classes)
        start = fold.start(view.labels, episodes, view.n_classes)
        chained = chain_of("mln", factors, evidence[held], fold.starts(episodes), None, 0.0, start)
        for decoding, out in zip(DECODERS, decode_all(chained, DECODERS)):
            predicted[decoding][held] = out.path
    scored = []
    for decoding in DECODERS:
        figures = figures_of(predicted[decoding][data.rows], data.split.labels, data.split.starts, view.n_classes,
                             True)
        scored.append({**figures, "criterion": criterion(figures), "decoder": decoding})
    return max(scored, key=lambda f: f[SCORE]), learned


def formulas(conjunctions: list[Conjunction]):
    """The MLN searched: the per-frame template, a template line per conjunction, and learned transitions."""
    from mlnseq.mln.syntax import parse_mln

    return parse_mln(formulas_text(conjunctions), "learned formulas")


def formulas_text(conjunctions: list[Conjunction], comments: list[str] | None = None) -> str:
    """The formulas as a .mln file: declarations, the per-frame template, the conjunctions (each under its comment,
    when given), the transitions."""
    lines = ["Has(word, page)", "Topic(class, page)", "Next(page, page)", "",
             "// every predicate value may indicate every class: one learned weight per value and class",
             "0.0 Has(+w, p) => Topic(+c, p)"]
    for k, body in enumerate(conjunctions):
        lines += ["", *([f"// {comments[k]}"] if comments else []),
                  f'0.0 Has("{body.first}", p) ^ Has("{body.second}", p) => Topic(+c, p)']
    lines += ["", "// transitions: a frame of class c1 followed by one of class c2, one learned weight per pair",
              "0.0 Topic(+c1, p) ^ Next(p, q) => Topic(+c2, q)"]
    return "\n".join(lines) + "\n"


def interacting(chosen: list[Candidate], data: Training) -> list[tuple[float, int, int]]:
    """Pairs of ``chosen`` whose joint values separate the classes beyond the two added: (the out-of-fold per-frame
    log-likelihood of the joint values above that of the two, i, j), largest first."""
    rows, split = data.rows, data.split
    found = []
    for i, a in enumerate(chosen):
        for j in range(i + 1, len(chosen)):
            joint, apart = [], []
            for k in range(split.k):
                (first, n_first), (second, n_second) = a.fold_codes(k), chosen[j].fold_codes(k)
                joint.append(quick_chain.one_hot([first[rows].astype(np.int64) * n_second + second[rows]],
                                                  [n_first * n_second]))
                apart.append(quick_chain.one_hot([first[rows], second[rows]], [n_first, n_second]))
            gained = quick_chain.per_frame_log_likelihood(joint, split) - \
                quick_chain.per_frame_log_likelihood(apart, split)
            found.append((gained, i, j))
    return sorted((item for item in found if item[0] > 0), reverse=True)


def bodies(a: Candidate, b: Candidate, data: Training) -> list[Conjunction]:
    """A conjunction per pair of values of ``a`` and ``b`` that holds in enough training frames."""
    view = data.frames
    least = max(10, MIN_SUPPORT * view.train.sum())
    found = []
    for u, first in enumerate(a.predicate.values):
        for v, second in enumerate(b.predicate.values):
            both = view.train & (a.codes == u) & (b.codes == v)
            if both.sum() >= least:
                found.append(Conjunction(f"{a.predicate.name}_{first}", f"{b.predicate.name}_{second}",
                                         np.bincount(view.labels[both], minlength=view.n_classes)))
    return found


def search(frames: pl.DataFrame, n_classes: int, most: int = SEARCH_FRAMES) -> Searched | None:
    """Learn the predicates and formulas of ``frames`` (sorted by episode and frame), on at most ``most`` of its
    training frames (``drawn``); None where the training split is too small for 2 folds."""
    data = training(frames, n_classes, most)
    if data is None:
        return None
    frames = data.table
    found, distances = channels(frames)
    made = candidates_of(found, data.frames)
    searched = Searched([], candidates=len(made), channels=len(found), folds=data.folds.describe(),
                        fold_record=data.record, frames=frames, sampled=data.sampled)
    near = None
    for chosen, (figures, near) in forward(pool(made, data), data):
        searched.path.append({"predicates": [c.predicate.name for c in chosen], **figures})
        searched.predicates, searched.figures = chosen, figures
    for _, i, j in interacting(searched.predicates, data)[:PAIRS]:
        more = bodies(searched.predicates[i], searched.predicates[j], data)
        if not more:
            continue
        figures, weights = exact(searched.predicates, searched.conjunctions + more, data, near)
        searched.path.append({"predicates": [c.predicate.name for c in searched.predicates],
                              "conjunctions": [f"{c.first} ^ {c.second}" for c in searched.conjunctions + more],
                              **figures})
        if figures[SCORE] > searched.figures[SCORE] + MIN_STEP:
            searched.conjunctions, searched.figures, near = searched.conjunctions + more, figures, weights
    return finished(searched, frames, data.frames, distances)


def finished(searched: Searched, frames: pl.DataFrame, view: Frames, distances: list[Distance]) -> Searched:
    """The search's result with the distances it reads and its formulas' weights on the whole training split (as
    `learn-weights` learns them)."""
    used = {c.channel for c in searched.predicates}
    searched.distances = [d for d in distances if d.name in used]
    train = (frames["split"] == Part.TRAIN).to_numpy()
    searched.train = train if train.any() else np.ones(frames.height, dtype=bool)
    if searched.predicates:
        columns = [f"{c.predicate.name}_{v}" for c in searched.predicates for v in c.predicate.values]
        splits = frames["split"].to_numpy() if train.any() else np.full(frames.height, Part.TRAIN)
        starts = chain_starts(frames["episode"].to_numpy(), splits)[searched.train]
        evidence = evidence_of(searched.predicates, frames.height)
        searched.weights = fold_weights(evidence[searched.train], view.labels[searched.train],
                                        starts, columns, formulas(searched.conjunctions), view.n_classes)
    return searched


UNCROSSED = 3  # predicates kept without folds: the grippers and the best of the others by information gain


def uncrossed(frames: pl.DataFrame, n_classes: int) -> Searched:
    """Without folds (or where no candidate gains out of fold): the candidates of best in-sample information gain,
    grippers first, ``UNCROSSED`` in all, not cross-validated."""
    train = (frames["split"] == Part.TRAIN).to_numpy()
    train = train if train.any() else np.ones(frames.height, dtype=bool)
    episodes = frames["episode"].to_numpy()
    labels = frames["label"].to_numpy().astype(np.int64)
    view = Frames(train, labels, chain_starts(episodes), np.where(train, 0, -1), n_classes)
    found, distances = channels(frames)
    made = sorted(candidates_of(found, view), key=lambda c: (c.kind != "gripper", -c.gain))
    kept, seen = [], set()
    for candidate in made:
        if candidate.channel not in seen and len(kept) < UNCROSSED:
            kept.append(candidate)
            seen.add(candidate.channel)
    result = Searched(kept, candidates=len(made), channels=len(found), frames=frames)
    return finished(result, frames, view, distances)
