"""The terms of a decoded frame's margin (stages/explaining/explainer.py says what they are): its formulas,
the network and the start distribution (its unary), the past and the future (the chain's messages), and the hard
rules that removed classes. A frame's parts (``FrameParts``) come from a whole recording's messages (``decoded``)
or from a stream's held frames (stages/explaining/streaming.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlnseq.catalog.decoders import Decoder
from mlnseq.catalog.methods import FUSED, Method
from mlnseq.mln.lag import FORBID, allowed
from mlnseq.explaining.explainer import Explainer, Gathered, Scores
from mlnseq.explaining.terms import Term, TermKind


@dataclass(slots=True)
class FrameParts:
    """What one decoded frame's decision is made of (a plain dataclass: a stream makes one a frame)."""

    row: np.ndarray  # [W] its evidence
    unary: np.ndarray  # [C] its unary as decoded (the start distribution in it at a chain's first frame)
    log_p_network: np.ndarray | None  # [C]
    first: bool  # a chain's first frame (the start distribution counts)
    forbidden: bool  # every class forbidden by its hard formulas: taken as uniform
    restarted: bool  # a dead end: the chain restarted here
    past: np.ndarray | None = None  # [C] what the frames before carry in (None: nothing, a chain start or dead end)
    before: np.ndarray | None = None  # [C] the previous frame's log forward vector
    previous: np.ndarray | None = None  # [W] the previous frame's evidence
    pairwise: np.ndarray | None = None  # [C, C] joining the previous frame
    joint: object = None  # what tells the pairwise apart (its row in the chain), for the texts' cache
    future: np.ndarray | None = None  # [C] what the frames after carry back (None: none)
    ahead: int = 0  # frames the future reads
    emitted: int | None = None  # a legal decoder: the class it emitted before (None: no rule on this frame)

    @property
    def scores(self) -> np.ndarray:
        out = self.unary if self.past is None else self.unary + self.past
        return out if self.future is None else out + self.future


def decoded(explainer: Explainer, scores: Scores, t: int, versus: int | None):
    """(chosen, versus, margin, terms) of frame ``t`` of a decoded recording."""
    return terms_of(explainer, parts_of(explainer, scores, t), int(scores.path[t]), versus)


def parts_of(explainer: Explainer, scores: Scores, t: int) -> FrameParts:
    """Frame ``t``'s parts from the recording's messages (``explainer.messages``)."""
    factors, messages, decoder = scores.factors, explainer.messages, explainer.scoring.decoding.decoder
    joined, reach = bool(messages.joined[t]), int(messages.reach[t])
    legal = decoder.legal and decoder is not Decoder.VITERBI and factors.link[t] >= 0
    pairwise = factors.pairwise[factors.link[t]] if factors.link[t] >= 0 else None
    return FrameParts(scores.evidence[t], messages.unary[t], None if scores.log_p_network is None
                      else scores.log_p_network[t], bool(factors.link[t] < 0),
                      bool(messages.restarted[t] and not np.isfinite(factors.unary[t]).any()),
                      bool(messages.restarted[t] and factors.link[t] >= 0),
                      messages.past[t] if joined else None, messages.before[t] if joined else None,
                      scores.evidence[t - 1] if t else None, pairwise, int(factors.link[t]),
                      messages.future[t] if reach > t else None, reach - t, int(scores.path[t - 1]) if legal else None)


def terms_of(explainer: Explainer, parts: FrameParts, chosen: int, versus: int | None):
    """(chosen, versus, margin, terms) of a frame from its parts."""
    gathered = Gathered()
    if versus is None and parts.emitted is None and np.isfinite(parts.scores).all():  # every class possible, no rule
        others = parts.scores.copy()
        others[chosen] = -np.inf
        versus = int(others.argmax())
        unary_terms(explainer, parts, chosen, versus, gathered)
        message_terms(explainer, parts, chosen, versus, gathered)
        return chosen, versus, float(parts.scores[chosen] - parts.scores[versus]), gathered
    score = parts.scores.tolist()  # a handful of classes: plain Python is quicker than numpy here
    possible = [value > -np.inf for value in score]
    ok = possible if parts.emitted is None else [
        p and a for p, a in zip(possible, allowed(parts.pairwise)[parts.emitted].tolist())]
    if versus is None:
        others = [k for k in range(len(score)) if ok[k] and k != chosen]
        versus = max(others, key=score.__getitem__) if others else None  # the first of equals, as argmax
    if not all(ok):
        gathered.terms += [removed(explainer, parts, k, possible[k]) for k in range(explainer.n_classes)
                           if k != chosen and not ok[k]]
    if versus is None or not (possible[chosen] and possible[versus]):
        if not possible[chosen]:
            gathered.notes.append("no class the decoder may emit here is possible given the frames: it took the first "
                                  "one allowed")
        return chosen, versus, None, gathered
    unary_terms(explainer, parts, chosen, versus, gathered)
    message_terms(explainer, parts, chosen, versus, gathered)
    return chosen, versus, float(score[chosen] - score[versus]), gathered


def unary_terms(explainer: Explainer, parts: FrameParts, a: int, b: int, gathered: Gathered) -> None:
    """The frame's own terms: its formulas, the network, the start distribution."""
    scoring = explainer.scoring
    if parts.forbidden:
        gathered.notes.append("every class is forbidden at this frame by its hard formulas: the decoders take it as "
                              "uniform, the chain restarting here")
        return
    if scoring.method == Method.MLN or scoring.method in FUSED:
        gathered.terms += explainer.formula_terms(parts.row, a, b)
    if scoring.network is not None and scoring.method != Method.MLN:
        log_p, weight = parts.log_p_network.tolist(), scoring.network_weight
        gathered.terms.append(Term(TermKind.NETWORK, f"{explainer.network_text}{log_p[a]:.2f} vs {log_p[b]:.2f}",
                                   weight * (log_p[a] - log_p[b]), weight=weight))
    if parts.first and scoring.start is not None:
        start = scoring.start
        gathered.terms.append(Term(TermKind.START, f"start distribution: log p {start[a]:.2f} vs {start[b]:.2f}",
                                   float(start[a] - start[b])))
    if parts.restarted:
        gathered.notes.append("a dead end: no class was possible given the frames before, so the chain restarted "
                              "here and the past counts for nothing")


def message_terms(explainer: Explainer, parts: FrameParts, a: int, b: int, gathered: Gathered) -> None:
    """The past (the forward message) and the future (the backward message over the decoder's window)."""
    semiring = "max-product" if explainer.semiring == "max" else "sum-product"
    if parts.past is not None:
        contribution = float(parts.past[a] - parts.past[b])
        text, line = past_text(explainer, parts, a, b, contribution >= 0)
        gathered.terms.append(Term(TermKind.PAST, f"frames before (forward message, {semiring}); {text}", contribution,
                                   line))
    if parts.future is not None:
        count = f"{parts.ahead} frame{'s' if parts.ahead > 1 else ''}"
        gathered.terms.append(Term(TermKind.FUTURE, f"frames after (backward message, {semiring}): the next {count}",
                                   float(parts.future[a] - parts.future[b])))


def past_text(explainer: Explainer, parts: FrameParts, a: int, b: int, upper: bool) -> tuple[str, int | None]:
    """The transition that bounds the past: sum-product, the one from the previous frame's class that favours ``a``
    over ``b`` most (``upper``) or least; max-product, the best ones into each."""
    names, pairwise, before = explainer.scoring.classes, parts.pairwise, parts.before
    key = (parts.joint, a, b, upper, (before > -np.inf).tobytes())  # a sum-product bound reads which were possible
    if explainer.semiring == "sum" and key in explainer.said:
        return explainer.said[key]
    if explainer.semiring == "max":
        into_a, into_b = int(np.argmax(before + pairwise[:, a])), int(np.argmax(before + pairwise[:, b]))
        line = transition_line(explainer, parts, into_a, a, b)
        return f"best into {names[a]} from {names[into_a]}, into {names[b]} from {names[into_b]}", line
    with np.errstate(invalid="ignore"):
        gain = np.where((before > -np.inf) & np.isfinite(pairwise[:, a]) & np.isfinite(pairwise[:, b]),
                        pairwise[:, a] - pairwise[:, b], np.nan)
    if np.isnan(gain).all():
        return "no previous class allows both", None
    source = int(np.nanargmax(gain) if upper else np.nanargmin(gain))
    explainer.said[key] = (f"bound {gain[source]:+.2f} by {names[source]} -> {names[a]} vs {names[source]} -> "
                           f"{names[b]}", transition_line(explainer, parts, source, a, b))
    return explainer.said[key]


def transition_line(explainer: Explainer, parts: FrameParts, source: int, a: int, b: int) -> int | None:
    """The line of the temporal formula that sets ``source -> a`` apart from ``source -> b`` most."""
    if not explainer.temporal:
        return None
    truths = explainer.pair_truths(parts.previous, parts.row)
    share = explainer.temporal_weights * (truths.true[source, a] - truths.true[source, b])
    if not np.any(share):
        return None
    return explainer.written_of(explainer.temporal[int(np.argmax(np.abs(share)))]).line


def removed(explainer: Explainer, parts: FrameParts, k: int, possible: bool) -> Term:
    """The hard-rule term of a class ``k`` no path reaches, or that a legal decoder may not emit here."""
    names = explainer.scoring.classes
    name = names[k]
    if not possible and parts.unary[k] == -np.inf:
        truths = explainer.frame_truths(parts.row)
        broken = [j for j in range(len(explainer.per_frame))
                  if explainer.scoring.formulas[explainer.per_frame[j]].hard and truths.broken[k, j]]
        return _rule(explainer, f"{name}: forbidden at this frame", [explainer.per_frame[j] for j in broken], name)
    if not possible and parts.past is not None and parts.past[k] == -np.inf:
        previous = np.flatnonzero(parts.before > -np.inf).tolist()
        return _rule(explainer, f"{name}: forbidden after {', '.join(names[y] for y in previous)}",
                     _hard_temporal(explainer, parts, previous, k), name)
    if not possible:
        return Term(TermKind.HARD_RULE, f"{name}: no path the rules allow from it through the next {parts.ahead} "
                    "frames", None, removed=name)
    emitted = parts.emitted
    cost = parts.pairwise[emitted]
    if cost[k] == -np.inf:
        return _rule(explainer, f"{name}: forbidden after {names[emitted]} (emitted before)",
                     _hard_temporal(explainer, parts, [emitted], k), name)
    return Term(TermKind.HARD_RULE, f"{name}: after {names[emitted]} (emitted before), its transition is "
                f"{cost.max() - cost[k]:.1f} nats below the best (over {FORBID:g}: never emitted)", None, removed=name)


def _hard_temporal(explainer: Explainer, parts: FrameParts, previous: list[int], k: int) -> list[int]:
    """The hard temporal formulas (indices into the Scoring's formulas) that forbid ``previous -> k`` here."""
    if not explainer.temporal:
        return []
    truths = explainer.pair_truths(parts.previous, parts.row)
    return [explainer.temporal[j] for j in range(len(explainer.temporal))
            if explainer.scoring.formulas[explainer.temporal[j]].hard and truths.broken[previous, k, j].any()]


def _rule(explainer: Explainer, text: str, formulas: list[int], name: str) -> Term:
    """A hard-rule term naming the lines (or, without them, the text) of ``formulas``."""
    from pathlib import Path

    found = [explainer.written_of(i) for i in formulas]
    lines = sorted({w.line for w in found if w.line is not None})
    files = {w.file for w in found if w.file is not None}
    if lines:
        where = f" by line{'s' if len(lines) > 1 else ''} {', '.join(map(str, lines))}"
        where += f" of {Path(files.pop()).name}" if len(files) == 1 else ""
    else:
        where = f" by {explainer.scoring.formulas[formulas[0]].text}" if formulas else ""
    first = found[0] if found else None
    return Term(TermKind.HARD_RULE, text + where, None, None if not lines else lines[0],
                None if first is None else first.file, written=None if first is None else first.text, removed=name)
