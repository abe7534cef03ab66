"""Explaining a stream's decisions as they are made (`stream --explain N`, ``Recognizer.explain_steps``).

Each stepped frame is recorded with what its decision reads: its evidence, its decoded unary (the start distribution
in it at an episode's first frame), the network's log-probabilities, the pairwise factor joining the previous frame,
and the forward vector before it (kept here, in log space, as stages/mln/chain_messages.py computes it). When the
decoder decides the frame (at once, or once frame t + lag has arrived), its future is the backward message over the
frames held after it, and its terms are those of a whole recording's frame (stages/explaining/decoded.py):
the same numbers. The decoders offline (posterior, Viterbi) stream as the filter, and are explained so.
"""

from __future__ import annotations

from dataclasses import replace
from json.encoder import encode_basestring_ascii as encode_text
from operator import attrgetter
from typing import Any

import numpy as np

from mlnseq.catalog.decoders import Decoder
from mlnseq.mln.chain_messages import carried_in, moved_back
from mlnseq.explaining.frames import scoring_of
from mlnseq.explaining.explainer import Explainer, Scores
from mlnseq.explaining.decoded import FrameParts, terms_of
from mlnseq.explaining.undecoded import undecoded
from mlnseq.explaining.terms import TermKind, Why, brief


SIZE = attrgetter("size")
MAX_ENCODED = 100_000  # formula terms whose JSON is kept (a stream's distinct evidence rows and class pairs)


class LiveExplainer:
    """Records a Recognizer's steps and explains each frame it decides: its ``count`` largest terms."""

    def __init__(self, recognizer: Any, count: int, epsilon: float):
        decoding = recognizer.decoding
        if recognizer.decode == "none":
            name = "none"
        elif decoding.decoder is Decoder.FILTER or decoding.decoder.offline:
            name = "filter"
        else:
            name = decoding.name
        self.explainer = Explainer(scoring_of(recognizer, name, epsilon))
        self.count = count
        decoding = self.explainer.scoring.decoding
        self.legal = decoding is not None and decoding.decoder.legal
        self.lag = 0 if decoding is None else decoding.lag or 0
        self.reset()

    def reset(self) -> None:
        """A new episode."""
        self.held: dict[int, Any] = {}  # frame -> its parts (FrameParts) or, undecoded, its Scores
        self.last: np.ndarray | None = None  # the last frame's forward vector, as the decoder holds it (normalised)
        self.row: np.ndarray | None = None  # the last frame's evidence
        self.emitted: int | None = None
        self._transitions: dict[bytes, tuple[np.ndarray, float]] = {}  # pairwise -> exp(pairwise - max), max
        self._encoded: dict[int, tuple[Any, dict, str]] = {}  # a formula term's id -> (the term, its dict, its JSON)

    def record_undecoded(self, index: int, row: np.ndarray | None, log_p_network: np.ndarray | None,
                         p_mln: np.ndarray | None) -> None:
        with np.errstate(divide="ignore"):
            log_mln = None if p_mln is None else np.log(p_mln)[None]
        self.held[index] = Scores(None if row is None else row[None], None if log_p_network is None
                                  else log_p_network[None], log_mln, None, np.zeros(1, dtype=np.int64), np.zeros(1))

    def record(self, index: int, row: np.ndarray, log_p_network: np.ndarray | None, unary: np.ndarray,
               pairwise: np.ndarray | None) -> None:
        """A decoded frame about to be stepped: its evidence, unary (start included), network and the pairwise joining
        it to the previous frame; ``stepped`` then gives the decoder's belief after it."""
        past = before = key = None
        if pairwise is not None and self.last is not None:
            key = pairwise.tobytes()
            before = _log(self.last)
            if self.explainer.semiring == "sum":  # log sum_y' alpha(y') exp(pairwise(y', y)), the matrix once
                if key not in self._transitions:
                    top = float(pairwise.max())
                    self._transitions[key] = (np.exp(pairwise - top), top)
                scaled, top = self._transitions[key]
                past = _log(self.last @ scaled) + top
            else:
                past = carried_in(before, pairwise, "max")
        self.held[index] = (row, unary, log_p_network, pairwise, past, before, self.row, key)
        self.row = row

    def stepped(self, index: int, belief: np.ndarray, restarted: bool) -> None:
        """The decoder's normalised belief after frame ``index`` (max-product: its max-marginals normalised), and
        whether the frame was a dead end."""
        row, unary, log_p_network, pairwise, past, before, previous, key = self.held[index]
        forbidden = not unary.max() > -np.inf
        joined = past is not None and not restarted
        self.held[index] = FrameParts(row, np.zeros_like(unary) if forbidden else unary, log_p_network,
                                      pairwise is None, forbidden, restarted and pairwise is not None,
                                      past if joined else None, before if joined else None,
                                      previous if joined else None, pairwise, key if joined else None)
        self.last = belief

    def decided(self, index: int, label: int, probabilities: np.ndarray) -> list[dict]:
        """The frame ``index`` decided as ``label``: its largest terms."""
        held = self.held.pop(index)
        if isinstance(held, Scores):
            _, _, _, gathered = undecoded(self.explainer, replace(held, path=np.array([label]),
                                                                    probabilities=probabilities[None]), 0, None)
        else:
            window = self._window(index)
            if window or (self.legal and not held.first):
                held = replace(held, future=self._future(window), ahead=len(window),
                               emitted=self.emitted if self.legal and not held.first else None)
            _, _, _, gathered = terms_of(self.explainer, held, label, None)
            self.emitted = label
        return self._why(sorted(gathered.terms, key=SIZE, reverse=True)[:self.count])

    def _why(self, terms: list) -> Why:
        """The terms' short dicts and their JSON text; a cached formula term's made once (kept with the term, so that
        its id is never another's)."""
        records, fragments = [], []
        for term in terms:
            cached = self._encoded.get(id(term))
            if cached is None or cached[0] is not term:
                [record] = brief([term])
                cached = (term, record, _encoded(record))
                if term.kind is TermKind.FORMULA and len(self._encoded) < MAX_ENCODED:
                    self._encoded[id(term)] = cached
            records.append(cached[1])
            fragments.append(cached[2])
        found = Why(records)
        found.json = "[" + ", ".join(fragments) + "]"
        return found

    def _window(self, index: int) -> list[FrameParts]:
        """The held frames after ``index`` that its decision reads (up to its lag, and a chain start or dead end)."""
        out = []
        for later in range(index + 1, index + self.lag + 1):
            frame = self.held.get(later)
            if frame is None or frame.first or frame.restarted:
                break
            out.append(frame)
        return out

    def _future(self, window: list[FrameParts]) -> np.ndarray | None:
        """The backward message over ``window`` (None: no frame after)."""
        if not window:
            return None
        vector = np.zeros(len(window[0].unary))
        for frame in reversed(window):
            vector = moved_back(frame.pairwise[None], (frame.unary + vector)[None], self.explainer.semiring)[0]
        return vector


def _log(values: np.ndarray) -> np.ndarray:
    """log of non-negative values, -inf for 0 (without numpy's warning, whose guard costs more than the log)."""
    if values.min() > 0:
        return np.log(values)
    with np.errstate(divide="ignore"):
        return np.log(values)


def _encoded(record: dict) -> str:
    """json.dumps of a term's short dict (kind, text, line, contribution), the same text made without its overhead."""
    line, contribution = record["line"], record["contribution"]
    return (f'{{"kind": "{record["kind"]}", "text": {encode_text(record["text"])}, '
            f'"line": {"null" if line is None else line}, '
            f'"contribution": {"null" if contribution is None else float.__repr__(contribution)}}}')
