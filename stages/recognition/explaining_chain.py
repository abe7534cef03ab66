"""The terms of a decoded frame's margin (stages/recognition/explaining.py says what they are): its formulas,
the network and the start distribution (its unary), the past and the future (the chain's messages), and the hard
rules that removed classes."""

from __future__ import annotations

import numpy as np

from mlnseq.catalog.decoders import Decoder
from mlnseq.catalog.methods import FUSED, Method
from mlnseq.mln.lag import FORBID
from mlnseq.recognition.explaining import Explainer, Gathered, Scores, allowed_after
from mlnseq.recognition.explanation import Term, TermKind


def decoded(explainer: Explainer, scores: Scores, t: int, versus: int | None):
    """(chosen, versus, margin, terms) of frame ``t`` of a decoded recording."""
    decoder, factors, score = explainer.scoring.decoding.decoder, scores.factors, explainer.messages.scores[t]
    chosen = int(scores.path[t])
    gathered = Gathered()
    ok = np.ones(explainer.n_classes, dtype=bool)
    legal = decoder.legal and decoder is not Decoder.VITERBI
    if legal and factors.link[t] >= 0:
        ok = allowed_after(factors, t, int(scores.path[t - 1]))
    possible = score > -np.inf
    if versus is None:
        others = possible & ok
        others[chosen] = False
        versus = int(np.argmax(np.where(others, score, -np.inf))) if others.any() else None
    for k in range(explainer.n_classes):
        if k != chosen and (not possible[k] or not ok[k]):
            gathered.terms.append(removed(explainer, scores, t, k, possible[k]))
    if versus is None or not (possible[chosen] and possible[versus]):
        if not possible[chosen]:
            gathered.notes.append("no class the decoder may emit here is possible given the frames: it took the first "
                                  "one allowed")
        return chosen, versus, None, gathered
    unary_terms(explainer, scores, t, chosen, versus, gathered)
    message_terms(explainer, scores, t, chosen, versus, gathered)
    return chosen, versus, float(score[chosen] - score[versus]), gathered


def unary_terms(explainer: Explainer, scores: Scores, t: int, a: int, b: int, gathered: Gathered) -> None:
    """The frame's own terms: its formulas, the network, the start distribution."""
    scoring, factors = explainer.scoring, scores.factors
    if explainer.messages.restarted[t] and not np.isfinite(factors.unary[t]).any():
        gathered.notes.append("every class is forbidden at this frame by its hard formulas: the decoders take it as "
                              "uniform, the chain restarting here")
        return
    if scoring.method == Method.MLN or scoring.method in FUSED:
        gathered.terms += explainer.formula_terms(scores.evidence[t], a, b)
    if scoring.network is not None and scoring.method != Method.MLN:
        log_p, weight = scores.log_p_network[t], scoring.network_weight
        gathered.terms.append(Term(TermKind.NETWORK, f"network ({scoring.network}) x {weight:.3g}: log p "
                                   f"{log_p[a]:.2f} vs {log_p[b]:.2f}", weight * float(log_p[a] - log_p[b]),
                                   weight=weight))
    if factors.link[t] < 0 and scoring.start is not None:
        start = scoring.start
        gathered.terms.append(Term(TermKind.START, f"start distribution: log p {start[a]:.2f} vs {start[b]:.2f}",
                                   float(start[a] - start[b])))
    if explainer.messages.restarted[t] and factors.link[t] >= 0:
        gathered.notes.append("a dead end: no class was possible given the frames before, so the chain restarted "
                              "here and the past counts for nothing")


def message_terms(explainer: Explainer, scores: Scores, t: int, a: int, b: int, gathered: Gathered) -> None:
    """The past (the forward message) and the future (the backward message over the decoder's window)."""
    messages, names = explainer.messages, explainer.scoring.classes
    semiring = "max-product" if messages.semiring == "max" else "sum-product"
    if messages.joined[t]:
        contribution = float(messages.past[t, a] - messages.past[t, b])
        text, line = past_text(explainer, scores, t, a, b, contribution >= 0)
        gathered.terms.append(Term(TermKind.PAST, f"frames before (forward message, {semiring}); {text}", contribution,
                                   line))
    reach = int(messages.reach[t])
    if reach > t:
        contribution = float(messages.future[t, a] - messages.future[t, b])
        count = f"{reach - t} frame{'s' if reach - t > 1 else ''}"
        gathered.terms.append(Term(TermKind.FUTURE, f"frames after (backward message, {semiring}): the next {count}, "
                                   f"to {names[int(scores.path[reach])]}", contribution))


def past_text(explainer: Explainer, scores: Scores, t: int, a: int, b: int, upper: bool) -> tuple[str, int | None]:
    """The transition that bounds the past: sum-product, the one from the previous frame's class that favours ``a``
    over ``b`` most (``upper``) or least; max-product, the best ones into each."""
    names, messages = explainer.scoring.classes, explainer.messages
    link = int(scores.factors.link[t])
    pairwise, before = scores.factors.pairwise[link], messages.before[t]
    key = (link, a, b, upper, (before > -np.inf).tobytes())  # a sum-product bound reads which classes were possible
    if messages.semiring == "sum" and key in explainer.said:
        return explainer.said[key]
    if messages.semiring == "max":
        into_a, into_b = int(np.argmax(before + pairwise[:, a])), int(np.argmax(before + pairwise[:, b]))
        line = transition_line(explainer, scores, t, into_a, a, b)
        return f"best into {names[a]} from {names[into_a]}, into {names[b]} from {names[into_b]}", line
    with np.errstate(invalid="ignore"):
        gain = np.where((before > -np.inf) & np.isfinite(pairwise[:, a]) & np.isfinite(pairwise[:, b]),
                        pairwise[:, a] - pairwise[:, b], np.nan)
    if np.isnan(gain).all():
        return "no previous class allows both", None
    source = int(np.nanargmax(gain) if upper else np.nanargmin(gain))
    explainer.said[key] = (f"bound {gain[source]:+.2f} by {names[source]} -> {names[a]} vs {names[source]} -> "
                           f"{names[b]}", transition_line(explainer, scores, t, source, a, b))
    return explainer.said[key]


def transition_line(explainer: Explainer, scores: Scores, t: int, source: int, a: int, b: int) -> int | None:
    """The line of the temporal formula that sets ``source -> a`` apart from ``source -> b`` most."""
    if not explainer.temporal:
        return None
    truths = explainer.pair_truths(scores.evidence[t - 1], scores.evidence[t])
    share = explainer.temporal_weights * (truths.true[source, a] - truths.true[source, b])
    if not np.any(share):
        return None
    return explainer.written_of(explainer.temporal[int(np.argmax(np.abs(share)))]).line


def removed(explainer: Explainer, scores: Scores, t: int, k: int, possible: bool) -> Term:
    """The hard-rule term of a class ``k`` no path reaches at ``t``, or that a legal decoder may not emit there."""
    names, factors, messages = explainer.scoring.classes, scores.factors, explainer.messages
    name = names[k]
    if not possible and factors.unary[t, k] == -np.inf:
        truths = explainer.frame_truths(scores.evidence[t])
        broken = [j for j in range(len(explainer.per_frame))
                  if explainer.scoring.formulas[explainer.per_frame[j]].hard and truths.broken[k, j]]
        return _rule(explainer, f"{name}: forbidden at this frame", [explainer.per_frame[j] for j in broken], name)
    if not possible and messages.joined[t] and messages.past[t, k] == -np.inf:
        previous = np.flatnonzero(messages.before[t] > -np.inf).tolist()
        return _rule(explainer, f"{name}: forbidden after {', '.join(names[y] for y in previous)}",
                     _hard_temporal(explainer, scores, t, previous, k), name)
    if not possible:
        reach = int(messages.reach[t])
        return Term(TermKind.HARD_RULE, f"{name}: no path the rules allow from it through the next {reach - t} "
                    "frames", None, removed=name)
    emitted = int(scores.path[t - 1])
    cost = factors.pairwise[factors.link[t]][emitted]
    if cost[k] == -np.inf:
        return _rule(explainer, f"{name}: forbidden after {names[emitted]} (emitted before)",
                     _hard_temporal(explainer, scores, t, [emitted], k), name)
    return Term(TermKind.HARD_RULE, f"{name}: after {names[emitted]} (emitted before), its transition is "
                f"{cost.max() - cost[k]:.1f} nats below the best (over {FORBID:g}: never emitted)", None, removed=name)


def _hard_temporal(explainer: Explainer, scores: Scores, t: int, previous: list[int], k: int) -> list[int]:
    """The hard temporal formulas (indices into the Scoring's formulas) that forbid ``previous -> k`` at ``t``."""
    if not explainer.temporal:
        return []
    truths = explainer.pair_truths(scores.evidence[t - 1], scores.evidence[t])
    return [explainer.temporal[j] for j in range(len(explainer.temporal))
            if explainer.scoring.formulas[explainer.temporal[j]].hard and truths.broken[previous, k, j].any()]


def _rule(explainer: Explainer, text: str, formulas: list[int], name: str) -> Term:
    """A hard-rule term naming the lines (or, without them, the text) of ``formulas``."""
    found = [explainer.written_of(i) for i in formulas]
    lines = sorted({w.line for w in found if w.line is not None})
    files = {w.file for w in found if w.file is not None}
    if lines:
        where = f" by line{'s' if len(lines) > 1 else ''} {', '.join(map(str, lines))}"
        where += f" of {_name(files.pop())}" if len(files) == 1 else ""
    else:
        where = f" by {explainer.scoring.formulas[formulas[0]].text}" if formulas else ""
    first = found[0] if found else None
    return Term(TermKind.HARD_RULE, text + where, None, None if not lines else lines[0],
                None if first is None else first.file, written=None if first is None else first.text, removed=name)


def _name(path: str) -> str:
    from pathlib import Path

    return Path(path).name
