"""A model's audit profile learned from its workdir: the labelled (and alignment-labelled) training recordings'
phases, durations and rules (profile.py), and each check's allowance chosen by cross-validation. Each training
recording is decoded by what was fitted without its fold (the fold's network and MLN, as conflate cross-validates)
and measured against the profile of the other training recordings; a check's allowance is MARGIN times the highest
measure a held-out recording got (at least the check's least), and how often a clean recording is flagged is
estimated the same way, each recording judged by allowances set without it. The least windowed chain
log-likelihood seen, less CHAIN_MARGIN, is where the chain finds a stretch unlikely. A workdir trained without folds
is measured in-sample (said in the calibration: recordings the model has seen look cleaner than new ones)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mlnseq.auditing import chains, scoring
from mlnseq.auditing.profile import (Calibration, Profile, boundary_error, calibrated_as, learn, profile_of,
                                     recordings, without)
from mlnseq.auditing.scoring import Check
from mlnseq.catalog import artifacts
from mlnseq.catalog.methods import Method, needs_mln, network_of
from mlnseq.catalog.parts import Part
from mlnseq.choosing.latency import rate_of
from mlnseq.choosing.workdir_inputs import WorkdirInputs, read_workdir
from mlnseq.mln.chain_factors import ChainFactors
from mlnseq.timeline import sequences

MARGIN = 1.25  # a check's allowance: this many times the highest measure of a held-out training recording
ROBUST = 5  # from this many held-out training recordings on, the highest measure is left out of the allowances
CHAIN_MARGIN = 0.1  # nats a frame below the least windowed chain log-likelihood of a held-out recording


def predicate_columns(recognizer: Any) -> list[tuple[str, str]]:
    """The model's predicate columns as (predicate, value), in its evidence order."""
    if recognizer.spec is None:
        return []
    return [(name, column[len(name) + 1:]) for name, columns in recognizer.spec.columns().items() for column in columns]


def calibrated(workdir: Path, recognizer: Any) -> Profile:
    """The audit profile of the model ``recognizer`` (a Recognizer) exported from ``workdir``."""
    network = network_of(recognizer.method) or Method.NETWORK  # the MLN alone: the folds come with the networks'
    inputs = read_workdir(Path(workdir), [str(network)])
    data = inputs.data
    train = (data.splits == Part.TRAIN) & (data.labels >= 0)
    evidence = None
    if recognizer.spec is not None and inputs.mln is not None:
        evidence = inputs.mln.predicates.select(recognizer.columns).to_numpy().astype(bool)
    columns, rate = predicate_columns(recognizer) if evidence is not None else [], rate_of(inputs.meta)
    episodes = [span for span in sequences.runs(data.episodes) if train[span].all()]
    found = out_of_fold(inputs, recognizer, learned_weights(Path(workdir), recognizer.method))
    how = "cross-validation" if found is not None else "in-sample"
    path, factors = found if found is not None else in_sample(recognizer, data.features, data.episodes)
    parts = [(span, path[span], _whole(factors, span)) for span in episodes]
    lows = [None if f is None else _lowest(rate or 1.0, chains.step_likelihood(f, p)) for _, p, f in parts]
    errors = [boundary_error(data.labels[span], own) for span, own, _ in parts]
    rows = np.concatenate([np.arange(span.start, span.stop) for span in episodes]) if episodes else np.zeros(0, int)
    recorded = recordings(data.labels[rows], data.episodes[rows], None if evidence is None else evidence[rows], rate)
    measures = []
    for k, (span, own, chained) in enumerate(parts):
        others, common = without(recorded, k)
        if not others:
            continue
        held = profile_of(others, recognizer.classes, columns, rate, common)
        held = calibrated_as(held, {}, _floor([low for j, low in enumerate(lows) if j != k]), Calibration(),
                             _rms([e for j, own in enumerate(errors) if j != k for e in own], rate))
        measures.append(_measured(held, own, None if evidence is None else evidence[span], chained))
    profile = learn(data.labels[train], data.episodes[train], None if evidence is None else evidence[train],
                    recognizer.classes, columns, rate)
    highest = {check.value: max((m.get(check.value, 0.0) for m in measures), default=0.0) for check in Check}
    flagged = sum(_flagged(m, [o for o in measures if o is not m]) for m in measures)
    accuracy = float(np.mean(path[rows] == data.labels[rows])) if len(rows) else None
    calibration = Calibration(len(measures), flagged, highest, how, accuracy)
    return calibrated_as(profile, _allowances(measures), _floor(lows), calibration,
                         _rms([e for own in errors for e in own], rate))


def _rms(frames: list[float], rate: float | None) -> float:
    """The root mean square of boundary errors (frames), in seconds (frames where the rate is unknown)."""
    return float(np.sqrt(np.mean(np.square(frames)))) / (rate or 1.0) if frames else 0.0


def _measured(profile: Profile, path: np.ndarray, evidence: np.ndarray | None,
              factors: ChainFactors | None) -> dict[str, float]:
    """A held-out recording's highest measure of each check."""
    decoded = chains.Decoded(path, evidence) if factors is None else chains.decoded(factors, evidence, path)
    audited = scoring.audit(profile, decoded)
    out: dict[str, float] = {}
    for reason in audited.reasons:
        check = reason.kind.check.value
        out[check] = max(out.get(check, 0.0), reason.measure)
    return out


def _allowances(measures: list[dict[str, float]]) -> dict[str, float]:
    """Each check's allowance: MARGIN times the highest measure of the held-out recordings, from ROBUST recordings
    on the highest but one (a fold whose network decoded its recording badly does not blind the audit), at least
    the check's least."""
    out = {}
    for check in Check:
        values = sorted((m.get(check.value, 0.0) for m in measures), reverse=True)
        kept = values[1:] if len(values) >= ROBUST else values
        out[check.value] = max(check.least, MARGIN * max(kept, default=0.0))
    return out


def _flagged(measure: dict[str, float], others: list[dict[str, float]]) -> bool:
    """Whether a held-out recording is suspect by allowances set from the other held-out recordings."""
    allowed = _allowances(others)
    return any(value >= allowed[check] for check, value in measure.items())


def _lowest(rate: float, likelihood: np.ndarray) -> float | None:
    """The least mean chain log-likelihood over a window of a recording."""
    if not len(likelihood):
        return None
    width = max(int(round(scoring.CHAIN_S * rate)), 1)
    means = scoring.windowed(likelihood, width)
    return float(means[min(width, len(means)) - 1:].min())


def _floor(lows: list[float | None]) -> float | None:
    """CHAIN_MARGIN below the least windowed chain log-likelihood of the held-out recordings (from ROBUST on: the
    least but one)."""
    known = sorted(low for low in lows if low is not None)
    kept = known[1:] if len(known) >= ROBUST else known
    return kept[0] - CHAIN_MARGIN if kept else None


def _whole(factors: dict[int, ChainFactors] | None, span: slice) -> ChainFactors | None:
    """The chain of the episode ``span`` where one fold holds it whole (a fold of blocks cuts a long episode)."""
    piece = None if factors is None else factors.get(span.start)
    return piece if piece is not None and len(piece.unary) == span.stop - span.start else None


def out_of_fold(inputs: WorkdirInputs, recognizer: Any, weights: list[float] | None = None
                ) -> tuple[np.ndarray, dict[int, ChainFactors] | None] | None:
    """Per row of the training split, its phases decoded (viterbi, or undecoded the argmax) from what was fitted
    without its fold, and each training episode's chain (by its first row; None undecoded); None without folds.
    ``weights``: each fold's network weight as conflate learned it (:func:`learned_weights`); None: learned here."""
    from mlnseq.choosing.cross_validation import weighted
    from mlnseq.fusion.fuse import chain_of

    cv, data, method = inputs.folds, inputs.data, recognizer.method
    network = network_of(method)
    if cv is None or (network is not None and network not in cv.log_probs) or \
            (needs_mln(method, recognizer.decode) and not cv.mln):
        return None
    log_p = cv.log_probs.get(network) if network is not None else None
    if recognizer.decode == "none":
        return _undecoded(inputs, recognizer, log_p), None
    from mlnseq.mln.factors import MLNFactors

    parts = []
    for k, fold in enumerate(cv.folds.masks()):
        mln = cv.mln[k]
        factors = MLNFactors.from_weights(mln.weights, mln.columns, inputs.classes)
        parts.append((fold.rows, chain_of(method, factors, mln.evidence[fold.rows], fold.starts(data.episodes),
                                          None if log_p is None else log_p[fold.rows], 0.0,
                                          fold.start(data.labels, data.episodes, len(inputs.classes)))))
    path = np.full(len(data.labels), -1, dtype=np.int64)
    pieces: dict[int, ChainFactors] = {}
    known = weights if weights is not None and len(weights) == len(parts) else None
    for rows, chained in weighted(parts, log_p, data.labels, known, []):
        for span in sequences.runs(data.episodes[rows]):
            piece = chains.piece(chained, span)
            pieces[int(rows[span.start])] = piece
            path[rows[span]] = chains.decoded_path(piece)
    return path, pieces


def learned_weights(workdir: Path, method: str) -> list[float] | None:
    """Each fold's network weight for ``method`` as conflate learned it on the other folds' chains (the weights
    :func:`out_of_fold` would learn again), or None where conflate kept none or was given one (--network-weight)."""
    path = workdir / artifacts.PREDICTIONS
    if not path.is_file():
        return None
    meta = artifacts.read_metadata(path, "predictions")
    if meta.get("network_weight_option") is not None or not meta.get("cross_validation"):
        return None
    learned = meta["cross_validation"].get("fold_network_weights", {})
    return next(([float(w) for w in weights] for name, weights in learned.items()
                 if name.partition("+")[0] == method), None)


def _undecoded(inputs: WorkdirInputs, recognizer: Any, log_p: np.ndarray | None) -> np.ndarray:
    from mlnseq.fusion.fuse import fuse
    from mlnseq.mln import classifier

    cv, path = inputs.folds, np.full(len(inputs.data.labels), -1, dtype=np.int64)
    for k, fold in enumerate(cv.folds.masks()):
        rows, mln = fold.rows, cv.mln[k] if cv.mln else None
        p_mln = None if mln is None else np.exp(classifier.class_log_probs(
            mln.scores[rows], recognizer.manifest.mln_mode, inputs.paper_floor))
        path[rows] = fuse(recognizer.method, None if log_p is None else np.exp(log_p[rows]), p_mln).argmax(1)
    return path


def in_sample(recognizer: Any, features: np.ndarray,
              episodes: np.ndarray) -> tuple[np.ndarray, dict[int, ChainFactors] | None]:
    """The model's own decoding of its training frames (viterbi where it decodes) and each episode's chain."""
    decoded = recognizer.decode != "none"
    scores = recognizer.scored(features, episodes, "viterbi" if decoded else "none")
    if not decoded:
        return scores.path, None
    return scores.path, {span.start: chains.piece(scores.factors, span) for span in sequences.runs(episodes)}
