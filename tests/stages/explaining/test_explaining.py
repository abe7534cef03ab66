"""Explanations add up: over random chains and weights, for every method and decoder a model file can hold, each
decided frame's terms sum to the margin the decoder used (its own probabilities, and a brute-force sum or max over
every class path), to 1e-6, and the class explained is the one the decoder chose. Every kind of term is seen to
count, so dropping one would fail."""

from __future__ import annotations

import itertools

import numpy as np
import polars as pl
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mlnseq.catalog.decoders import Decoder, parse_decoding
from mlnseq.catalog.methods import Method, MLNMode, PaperFloor
from mlnseq.mln import chain, classifier
from mlnseq.mln.factors import MLNFactors, parse_weights
from mlnseq.explaining.frames import explain
from mlnseq.explaining.explainer import Explainer, Scores, Scoring
from mlnseq.explaining.terms import TermKind
from mlnseq.fusion import decoding as decoders
from mlnseq.fusion.fuse import EPSILON, chain_of, fuse

WORDS = ("w0", "w1", "w2")
CLASSES = ("a", "b", "c")
DECODINGS = ("filter", "filter-legal", "smooth@2", "smooth-legal@1", "lagviterbi@2", "lagviterbi-legal@3",
             "posterior", "posterior-legal", "viterbi")
DECODED = (Method.MLN, Method.NETWORK, Method.CONFLATION, Method.COMBINED)
UNDECODED = (Method.NETWORK, Method.MLN, Method.CONFLATION)
EXAMPLES = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow])


def weights_table(rng: np.random.Generator, hard: int) -> pl.DataFrame:
    """Random weights for every Has(w) => Topic(c) and Topic(c1) ^ Next => Topic(c2); ``hard`` 1: a hard per-frame
    rule and a hard transition rule; 2: rules that force classes too, so that some frames are dead ends."""
    rows = [(f'Has("{w}",p) => Topic("{c}",p)', float(rng.normal()), False) for w in WORDS for c in CLASSES]
    rows += [(f'Topic("{c1}",p) ^ Next(p,q) => Topic("{c2}",q)', float(rng.normal()), False)
             for c1 in CLASSES for c2 in CLASSES]
    if hard:
        rows += [('Has("w0",p) ^ Has("w1",p) => !Topic("c",p)', 0.0, True),
                 ('Topic("a",p) ^ Next(p,q) => !Topic("c",q)', 0.0, True)]
    if hard > 1:
        rows += [('Has("w2",p) ^ !Has("w0",p) => Topic("c",p)', 0.0, True),
                 ('Has("w1",p) ^ !Has("w2",p) => Topic("a",p)', 0.0, True)]
    return pl.DataFrame({"formula": [r[0] for r in rows], "weight": [r[1] for r in rows],
                         "hard": [r[2] for r in rows]})


def recording(seed: int, frames: int, hard: int):
    """A random recording: evidence, two episodes, network log-probabilities, an MLN."""
    rng = np.random.default_rng(seed)
    weights = weights_table(rng, hard)
    evidence = rng.random((frames, len(WORDS))) < 0.5
    episodes = np.repeat([0, 1], [frames - frames // 3, frames // 3])
    logits = rng.normal(size=(frames, len(CLASSES))) * 2
    log_p = logits - np.log(np.exp(logits).sum(axis=1, keepdims=True))
    start = np.log(rng.dirichlet(np.ones(len(CLASSES))))
    return weights, evidence, episodes, log_p, start, float(rng.uniform(0.2, 2.0))


def scoring(method: Method, decode: str, weights: pl.DataFrame, start, weight: float, mode=MLNMode.PAPER,
            floor=PaperFloor.CLAMP) -> Scoring:
    formulas = tuple(parse_weights(weights, WORDS, CLASSES))
    decoding = None if decode == "none" else parse_decoding(decode)
    network = None if method == Method.MLN else ("priorlayer" if method == Method.COMBINED else "lstm")
    return Scoring(method, decoding, CLASSES, WORDS, formulas, (), network, weight, start, mode, floor, EPSILON)


def brute_margins(factors: chain.ChainFactors, t: int, decode: str) -> np.ndarray:
    """Each class's score at frame t by enumerating every class path of the frames its decision reads."""
    decoding = parse_decoding(decode)
    first = max(s for s in np.flatnonzero(factors.link < 0) if s <= t)
    ends = [s - 1 for s in np.flatnonzero(factors.link < 0) if s > t]
    last = ends[0] if ends else len(factors.link) - 1
    if decoding.decoder.free is Decoder.FILTER:
        last = t
    elif not decoding.decoder.offline:
        last = min(last, t + decoding.lag)
    frames = range(first, last + 1)
    best = np.full(factors.n_classes, -np.inf)
    totals: list[list[float]] = [[] for _ in range(factors.n_classes)]
    for path in itertools.product(range(factors.n_classes), repeat=len(frames)):
        score = sum(factors.unary[f, y] for f, y in zip(frames, path))
        score += sum(factors.pairwise[factors.link[f], path[i - 1], path[i]] for i, f in enumerate(frames) if i)
        y = path[t - first]
        best[y] = max(best[y], score)
        totals[y].append(score)
    if decoding.decoder.semiring == "max":
        return best
    return np.array([np.logaddexp.reduce(values) if values else -np.inf for values in totals])


def check(explanations, scores: Scores, classes=CLASSES) -> None:
    for found in explanations:
        assert found.chosen == classes[int(scores.path[found.row])]
        if found.margin is not None:
            assert abs(found.total() - found.margin) < 1e-6, found


def decoded_explanations(seed: int, frames: int, hard: int, method: Method, decode: str):
    """(explanations of every frame, the scores, the chain, what the decoder gave) of a random recording."""
    weights, evidence, episodes, log_p, start, weight = recording(seed, frames, hard)
    mln = MLNFactors.from_weights(weights, WORDS, CLASSES)
    factors = chain_of(method, mln, evidence, chain.chain_starts(episodes), log_p, weight, start)
    decoded = decoders.decode(factors, decode)
    scores = Scores(evidence, log_p, None, factors, decoded.path, decoded.probabilities, decode)
    explanations = explain(Explainer(scoring(method, decode, weights, start, weight)), scores, list(range(frames)))
    return explanations, scores, factors, decoded


@EXAMPLES
@given(seed=st.integers(0, 2**31), frames=st.integers(2, 7), hard=st.integers(0, 2),
       method=st.sampled_from(DECODED), decode=st.sampled_from(DECODINGS))
def test_a_decoded_frames_terms_add_up_to_its_margin(seed, frames, hard, method, decode):
    explanations, scores, factors, decoded = decoded_explanations(seed, frames, hard, method, decode)
    check(explanations, scores)
    semiring = parse_decoding(decode).decoder.semiring
    for found in explanations:
        if found.margin is None:
            continue
        a, b = CLASSES.index(found.chosen), CLASSES.index(found.versus)
        if decode != "viterbi":  # the decoder's own numbers: its probabilities (max-product: normalised max-marginals)
            p = decoded.probabilities[found.row]
            assert abs(np.log(p[a]) - np.log(p[b]) - found.margin) < 1e-6
        if not len(decoded.restarts):  # no dead end: every path of the frames read counts
            brute = brute_margins(factors, found.row, decode)
            assert abs(brute[a] - brute[b] - found.margin) < 1e-6, (semiring, found)
            if not parse_decoding(decode).decoder.legal or decode == "viterbi":
                assert brute[a] >= brute.max() - 1e-9  # the chosen class is the best of the decoder's scores


@EXAMPLES
@given(seed=st.integers(0, 2**31), frames=st.integers(1, 6), method=st.sampled_from(UNDECODED),
       mode=st.sampled_from(list(MLNMode)), floor=st.sampled_from(list(PaperFloor)))
def test_an_undecoded_frames_terms_add_up_to_its_margin(seed, frames, method, mode, floor):
    weights, evidence, _, log_p, _, _ = recording(seed, frames, 1)
    predicates = pl.DataFrame({w: evidence[:, i] for i, w in enumerate(WORDS)})
    log_mln = classifier.class_log_probs(classifier.class_scores(predicates, weights, CLASSES), mode, floor)
    probabilities = fuse(method, np.exp(log_p), np.exp(log_mln))
    scores = Scores(evidence, log_p, log_mln, None, probabilities.argmax(1), probabilities)
    explanations = explain(Explainer(scoring(method, "none", weights, None, 1.0, mode, floor)), scores,
                           list(range(frames)))
    check(explanations, scores)
    for found in explanations:  # the margin is the log-ratio of the probabilities predict gives
        p = probabilities[found.row]
        a, b = CLASSES.index(found.chosen), CLASSES.index(found.versus)
        assert abs(np.log(p[a]) - np.log(p[b]) - found.margin) < 1e-6


def test_versus_names_the_class_compared_with():
    weights, evidence, episodes, log_p, start, weight = recording(3, 6, 0)
    mln = MLNFactors.from_weights(weights, WORDS, CLASSES)
    factors = chain_of(Method.COMBINED, mln, evidence, chain.chain_starts(episodes), log_p, weight, start)
    decoded = decoders.decode(factors, "smooth@2")
    scores = Scores(evidence, log_p, None, factors, decoded.path, decoded.probabilities, "smooth@2")
    explainer = Explainer(scoring(Method.COMBINED, "smooth@2", weights, start, weight))
    for versus in range(len(CLASSES)):
        for found in explain(explainer, scores, list(range(6)), versus):
            assert found.versus == CLASSES[versus]
            p = decoded.probabilities[found.row]
            assert abs(np.log(p[CLASSES.index(found.chosen)]) - np.log(p[versus]) - found.margin) < 1e-6


@pytest.mark.parametrize("kind", [TermKind.FORMULA, TermKind.NETWORK, TermKind.START, TermKind.PAST, TermKind.FUTURE,
                                  TermKind.HARD_RULE])
def test_every_kind_of_term_counts_so_that_dropping_it_breaks_the_sum(kind):
    broken = removed = 0
    for seed, (method, decode) in enumerate(itertools.product(DECODED, DECODINGS)):
        for found in decoded_explanations(seed, 7, 2, method, decode)[0]:
            removed += any(term.kind is TermKind.HARD_RULE for term in found.terms)
            rest = sum(t.contribution for t in found.terms if t.kind is not kind and t.contribution is not None)
            broken += found.margin is not None and abs(rest - found.margin) > 1e-6
    assert (removed if kind is TermKind.HARD_RULE else broken) > 0
