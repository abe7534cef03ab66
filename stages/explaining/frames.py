"""Explanations of a recording's frames: the decoded methods' (stages/explaining/decoded.py) and the
undecoded ones' (stages/explaining/undecoded.py), from what a Scoring scored (stages/explaining/explainer.py)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.methods import Method, network_of
from mlnseq.mln import chain_messages
from mlnseq.mln.formula_sources import Written, read_written
from mlnseq.fusion.decoding import decoding_of
from mlnseq.explaining.explainer import Explainer, Keys, Scores, Scoring, how
from mlnseq.explaining.decoded import decoded
from mlnseq.explaining.undecoded import undecoded
from mlnseq.explaining.terms import Explanation


def explain(explainer: Explainer, scores: Scores, rows: list[int], versus: int | None = None,
            keys: Keys | None = None) -> list[Explanation]:
    """The explanations of frames ``rows`` of a recording (against ``versus``, else each one's runner-up)."""
    scoring = explainer.scoring
    if scoring.decoding is not None and explainer.scored is not scores:
        decoder = scoring.decoding.decoder
        explainer.messages = chain_messages.messages(scores.factors, decoder.semiring,
                                                     None if decoder.offline else scoring.decoding.lag)
        explainer.scored = scores
    if scores.evidence is not None and len(rows) > 1:
        wanted = np.unique(np.clip(np.r_[rows, np.asarray(rows) - 1], 0, None))
        link = None if scores.factors is None else np.where(np.isin(np.arange(len(scores.path)), rows),
                                                            scores.factors.link, -1)
        explainer.prepare(scores.evidence[wanted] if link is None else scores.evidence, link)
    explained = undecoded if scoring.decoding is None else decoded
    out = []
    for t in rows:
        chosen, other, margin, gathered = explained(explainer, scores, t, versus)
        episode, frame, time = (None, t, None) if keys is None else keys.at(t)
        classes = scoring.classes
        terms = tuple(sorted(gathered.terms, key=lambda term: -term.size))  # largest first, hard rules first of all
        out.append(Explanation(t, episode, frame, classes[chosen], None if other is None else classes[other], margin,
                               terms, how(scoring), time, tuple(gathered.notes)))
    return out


def scoring_of(recognizer: Any, decode: str, epsilon: float) -> Scoring:
    """What a Recognizer (stages/recognition/recognizer.py) scores with, decoded with ``decode``."""
    written: tuple[Written, ...] = ()
    if recognizer.weights is not None:
        rows = read_written(recognizer.weights)
        counted = [not (weight == 0.0 and not hard) for weight, hard in recognizer.weights.select("weight", "hard")
                   .iter_rows()]  # the rows parse_weights keeps
        written = tuple(row for row, kept in zip(rows, counted) if kept)
    network = network_of(recognizer.method)
    manifest = recognizer.manifest
    return Scoring(Method(recognizer.method), None if decode == "none" else decoding_of(decode),
                   tuple(recognizer.classes), tuple(getattr(recognizer, "columns", ())), recognizer.formulas, written,
                   None if network is None else str(network), recognizer.network_weight, recognizer.start,
                   manifest.mln_mode, manifest.paper_floor, epsilon)


def class_index(classes: Sequence[str], name: str | None, option: str = "versus") -> int | None:
    """A class named by the user, as its index; an unknown one is refused naming the classes."""
    if name is None:
        return None
    if name not in classes:
        raise BadInput(f"{option} {name!r} is not a class of the model: {', '.join(classes)}")
    return list(classes).index(name)


def explain_recognized(recognizer: Any, frame: Any, versus: str | None, episodes: np.ndarray | None,
                       decode: str | None, epsilon: float) -> Explanation | list[Explanation]:
    """``Recognizer.explain``: a row of the last prediction, every frame of a recording, or one frame alone."""
    whole = not isinstance(frame, (int, np.integer)) or isinstance(frame, bool)
    if whole:
        features = np.asarray([recognizer.vector(frame)] if isinstance(frame, Mapping) or np.ndim(frame) == 1
                              else frame, dtype=np.float64)
        scores = recognizer.scored(features, episodes, decode)
        rows = list(range(len(features)))
    else:
        scores = recognizer.last
        if scores is None:
            raise BadInput("explain(row) explains a row of the recording the last predict was given: call predict "
                           "first, or pass the recording's features")
        if not 0 <= int(frame) < len(scores.path):
            raise BadInput(f"row {int(frame)} is outside the last prediction's {len(scores.path):,} rows")
        rows = [int(frame)]
    explainer = Explainer(scoring_of(recognizer, scores.decode, epsilon))
    keys = Keys(list(scores.episodes.tolist()), scores.frames)
    out = explain(explainer, scores, rows, class_index(recognizer.classes, versus), keys)
    single = not whole or isinstance(frame, Mapping) or np.ndim(frame) == 1
    return out[0] if single else out
