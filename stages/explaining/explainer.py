"""A decided frame's margin as the exact sum of its terms (stages/explaining/terms.py holds the terms).

Decoded methods (a chain): each frame's decision scores are, up to a constant per frame (stages/mln/chain_messages.py),

  score_t(y) = unary_t(y) + past_t(y) + future_t(y),
  unary_t(y) = sum_f w_f truth_f(t, y) + w_net log p_net(t, y) + start(y) (at a chain's first frame),

the formulas for the methods with the MLN's per-frame factor (mln, conflation, combined), the network for every
method but mln; filter, smoothing and posterior take the sum-product messages, lagged Viterbi and Viterbi the
max-product ones (the best path into the frame and out of it: a Viterbi path's class at t is the argmax of those
max-marginals). The margin between two classes is the difference of their scores, term by term. A class no path
reaches (a hard rule), or that a legal decoder may not emit after the class it emitted before, is a hard-rule term.

Undecoded methods are not a chain's sum; their margin log P(a) - log P(b) splits exactly by the rescale rule
(DeepLIFT's: each input's share of a difference is its share of the difference it enters): the network alone is one
term; the MLN's classes come from the formulas' score difference D = s_a - s_b by a function that keeps its sign
(softmax: itself; the paper's floored sums: log g(s_a) - log g(s_b), g increasing), so each formula gets its share
d_f / D of the margin (the hard formulas counted with the weight the classifier gives them); eq. 16 adds the network's
and the MLN's log-odds, so each side gets its share of their log-odds difference, the MLN's then split as above.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mlnseq.catalog.decoders import Decoding
from mlnseq.catalog.methods import FUSED, Method, MLNMode, PaperFloor
from mlnseq.mln import chain_messages, classifier
from mlnseq.mln.chain_factors import ChainFactors
from mlnseq.mln.distinct_rows import distinct_rows
from mlnseq.mln.factors import LearnedFormula, frame_space
from mlnseq.mln.features import PairColumns, read_columns
from mlnseq.mln.formula_sources import Written
from mlnseq.mln.formula_truths import Truths, frame_truths, pair_truths
from mlnseq.explaining.terms import Term, TermKind

TINY = 1e-12  # a score difference this small is no difference: the rescale rule gives it nothing


@dataclass(frozen=True)
class Scoring:
    """What a method scores frames with: a model file's, or a workdir's."""

    method: Method
    decoding: Decoding | None  # None: undecoded
    classes: tuple[str, ...]
    columns: tuple[str, ...]  # the evidence columns
    formulas: tuple[LearnedFormula, ...] = ()  # the MLN's formulas that count (factors.parse_weights)
    written: tuple[Written, ...] = ()  # where each was written
    network: str | None = None  # lstm or priorlayer
    network_weight: float = 1.0
    start: np.ndarray | None = None
    mln_mode: MLNMode = MLNMode.PAPER
    paper_floor: PaperFloor = PaperFloor.CLAMP
    epsilon: float = 1e-7  # where eq. 16 clips each side's probabilities (recognizer.EPSILON)

    @property
    def name(self) -> str:
        return str(self.method) if self.decoding is None else f"{self.method}+{self.decoding.name}"


@dataclass(frozen=True)
class Scores:
    """One recording as the method scored and decided it."""

    evidence: np.ndarray | None  # [T, W] bool
    log_p_network: np.ndarray | None  # [T, C]
    log_p_mln: np.ndarray | None  # [T, C] the MLN's class log-probabilities (undecoded methods)
    factors: ChainFactors | None  # decoded methods: the chain as decoded, its start distribution added
    path: np.ndarray  # [T] the decided classes
    probabilities: np.ndarray  # [T, C] as the decoder gave them
    decode: str = "none"  # the decoding that decided them
    episodes: np.ndarray | None = None  # [T] each row's episode, as given
    frames: np.ndarray | None = None  # [T] each row's frame within its episode


@dataclass
class Gathered:
    """One frame's terms and notes while they are gathered."""

    terms: list[Term] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


class Explainer:
    """Explains the frames of recordings a Scoring scored; formula truths are cached per evidence row and pair."""

    def __init__(self, scoring: Scoring):
        self.scoring = scoring
        self.semiring = "sum" if scoring.decoding is None else scoring.decoding.decoder.semiring
        self.network_text = f"network ({scoring.network}) x {scoring.network_weight:.3g}: log p "
        self.n_classes = len(scoring.classes)
        self.per_frame = [i for i, f in enumerate(scoring.formulas) if not f.temporal]
        self.temporal = [i for i, f in enumerate(scoring.formulas) if f.temporal]
        frame_formulas = [scoring.formulas[i] for i in self.per_frame]
        self.chain_weights = np.array([0.0 if f.hard else f.weight for f in frame_formulas])
        self.classifier_weights = np.array([classifier.HARD_WEIGHT if f.hard else f.weight for f in frame_formulas])
        self.temporal_weights = np.array([0.0 if scoring.formulas[i].hard else scoring.formulas[i].weight
                                          for i in self.temporal])
        columns = list(scoring.columns)
        self._frame_formulas = [f.formula for f in frame_formulas]
        self._temporal_formulas = [scoring.formulas[i].formula for i in self.temporal]
        self._frame_columns = read_columns(self._frame_formulas, columns)
        self._frame_space = frame_space([columns[i] for i in self._frame_columns], self.n_classes)
        self._pair_columns = PairColumns.of(self._temporal_formulas, columns)
        self._pair_space = frame_space([columns[i] for i in self._pair_columns.read], self.n_classes)
        self._frames: dict[bytes, Truths] = {}
        self._pairs: dict[bytes, Truths] = {}
        self._terms: dict[tuple, list[Term]] = {}
        self.shares: dict[tuple, tuple[float, list]] = {}  # undecoded: the formulas' score differences, by row
        self.said: dict[tuple, tuple[str, int | None]] = {}  # the texts of sum-product pasts, by what they read
        self.messages: chain_messages.Messages | None = None
        self.scored: Scores | None = None  # the recording the messages are of

    # -- formula truths: per distinct evidence (over the columns the formulas read) -----------------------

    def prepare(self, evidence: np.ndarray, link: np.ndarray | None) -> None:
        """Count the truths of every distinct evidence row (and consecutive pair joined by ``link``) at once."""
        if self.per_frame:
            rows = distinct_rows(evidence[:, self._frame_columns])[0]
            fresh = [row for row in rows if row.tobytes() not in self._frames]
            if fresh:
                found = frame_truths(self._frame_formulas, np.array(fresh), self._frame_space)
                self._frames.update({row.tobytes(): Truths(found.true[i], found.broken[i])
                                     for i, row in enumerate(fresh)})
        joined = np.flatnonzero(link >= 0) if link is not None and self.temporal else np.zeros(0, dtype=np.int64)
        if len(joined):
            keys = distinct_rows(self._pair_columns.keys(evidence[joined - 1], evidence[joined]))[0]
            fresh = np.array([key for key in keys if key.tobytes() not in self._pairs])
            if len(fresh):
                found = pair_truths(self._temporal_formulas, *self._pair_columns.rows(fresh), self._pair_space)
                self._pairs.update({key.tobytes(): Truths(found.true[i], found.broken[i])
                                    for i, key in enumerate(fresh)})

    def frame_key(self, row: np.ndarray) -> bytes:
        """What tells evidence rows apart for the per-frame formulas."""
        return row[self._frame_columns].tobytes()

    def frame_truths(self, row: np.ndarray) -> Truths:
        """The per-frame formulas' truths [C, F] on one evidence row."""
        key = self.frame_key(row)
        if key not in self._frames:
            found = frame_truths(self._frame_formulas, row[self._frame_columns][None], self._frame_space)
            self._frames[key] = Truths(found.true[0], found.broken[0])
        return self._frames[key]

    def pair_truths(self, previous: np.ndarray, current: np.ndarray) -> Truths:
        """The temporal formulas' truths [C, C, F] on one pair of consecutive evidence rows."""
        key = self._pair_columns.keys(previous[None], current[None])
        if key.tobytes() not in self._pairs:
            found = pair_truths(self._temporal_formulas, *self._pair_columns.rows(key), self._pair_space)
            self._pairs[key.tobytes()] = Truths(found.true[0], found.broken[0])
        return self._pairs[key.tobytes()]

    def formula_terms(self, row: np.ndarray, a: int, b: int) -> list[Term]:
        """The per-frame formulas' terms of a chain's unary on one evidence row, ``a`` against ``b`` (cached)."""
        key = (row.tobytes(), a, b)
        if key not in self._terms:
            truths = self.frame_truths(row)
            differences = truths.true[a] - truths.true[b]
            self._terms[key] = [self.formula_term(self.per_frame[j], float(self.chain_weights[j] * differences[j]),
                                                  (int(truths.true[a, j]), int(truths.true[b, j])),
                                                  float(self.chain_weights[j]))
                                for j in np.flatnonzero(differences * self.chain_weights).tolist()]
        return list(self._terms[key])

    def formula_term(self, index: int, contribution: float, truth: tuple[int, int], weight: float) -> Term:
        """A term of formula ``index`` of the Scoring's formulas."""
        formula, written = self.scoring.formulas[index], self.written_of(index)
        return Term(TermKind.FORMULA, formula.text, contribution, written.line, written.file, weight, truth,
                    written.text)

    def written_of(self, index: int) -> Written:
        return self.scoring.written[index] if index < len(self.scoring.written) else Written()

@dataclass(frozen=True)
class Keys:
    """Where each row of a recording is: its episode (the user's id), frame within it and time."""

    episode: list
    frame: np.ndarray
    time: np.ndarray | None = None

    def at(self, row: int) -> tuple[object, int, float | None]:
        return (self.episode[row], int(self.frame[row]),
                None if self.time is None else float(self.time[row]))


def how(scoring: Scoring) -> str:
    """The decoder and the messages its explanation takes."""
    if scoring.decoding is None:
        if scoring.method in FUSED:
            return f"{scoring.name} (eq. 16: shares of the log-odds)"
        return scoring.name + (" (the formulas' shares of the score difference)" if scoring.method == Method.MLN
                               else "")
    semiring = "max-product: the best paths" if scoring.decoding.decoder.semiring == "max" else "sum-product"
    return f"{scoring.name} ({semiring})"
