"""Exact chain inference (mlnseq.mln.chain) against enumeration of every path, and its online form."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.special import logsumexp

from mlnseq.mln.chain import (
    ChainFactors, Filter, chain_starts, filtered, log_partition, path_score, smoothed, viterbi,
)
from mlnseq.mln.chain_moments import count_covariance, expectations
from mlnseq.mln.chain_scan import Repeats


def random_factors(rng: np.random.Generator, frames: int, classes: int, rows: int = 2, forbid: float = 0.0,
                   cuts: float = 0.2) -> ChainFactors:
    unary = rng.normal(size=(frames, classes)) * 2
    pairwise = rng.normal(size=(rows, classes, classes)) * 2
    pairwise[rng.random(pairwise.shape) < forbid] = -np.inf
    link = rng.integers(0, rows, size=frames)
    link[rng.random(frames) < cuts] = -1
    link[0] = -1
    return ChainFactors(unary, pairwise, link)


def enumerate_chain(factors: ChainFactors, first: int, end: int) -> tuple[list[tuple[int, ...]], np.ndarray]:
    """Every class path of frames first..end-1 (one chain) and its log-potential."""
    paths = list(itertools.product(range(factors.n_classes), repeat=end - first))
    scores = np.array([factors.unary[np.arange(first, end), list(path)].sum()
                       + sum(factors.pairwise[factors.link[first + i], path[i - 1], path[i]] for i in range(1, len(path)))
                       for path in paths])
    return paths, scores


def brute_force(factors: ChainFactors) -> dict:
    """log Z, marginals, prefix (filtered) marginals, pair marginals per pairwise row, and the best path."""
    frames, classes = factors.unary.shape
    bounds = [*np.flatnonzero(factors.link < 0), frames]
    log_z, best, best_score = 0.0, np.zeros(frames, dtype=np.int64), 0.0
    marginal, prefix = np.zeros((frames, classes)), np.zeros((frames, classes))
    pairs = np.zeros((len(factors.pairwise), classes, classes))
    for first, end in zip(bounds[:-1], bounds[1:]):
        paths, scores = enumerate_chain(factors, first, end)
        chain_z = logsumexp(scores)
        log_z += chain_z
        weights = np.exp(scores - chain_z)
        best[first:end] = paths[int(scores.argmax())]
        best_score += scores.max()
        for path, weight in zip(paths, weights):
            marginal[np.arange(first, end), list(path)] += weight
            for i in range(1, len(path)):
                pairs[factors.link[first + i], path[i - 1], path[i]] += weight
        for last in range(first, end):
            head, head_scores = enumerate_chain(factors, first, last + 1)
            head_weights = np.exp(head_scores - logsumexp(head_scores))
            for path, weight in zip(head, head_weights):
                prefix[last, path[-1]] += weight
    return {"log_z": log_z, "marginal": marginal, "prefix": prefix, "pairs": pairs, "best": best, "best_score": best_score}


@pytest.mark.parametrize("seed", range(12))
def test_every_quantity_matches_enumeration(seed: int) -> None:
    rng = np.random.default_rng(seed)
    factors = random_factors(rng, int(rng.integers(1, 8)), int(rng.integers(2, 4)), forbid=0.15 if seed % 2 else 0.0)
    exact = brute_force(factors)
    if not np.isfinite(exact["log_z"]):
        pytest.skip("this draw has a chain with no possible path (dead ends are tested below)")
    assert log_partition(factors) == pytest.approx(exact["log_z"], abs=1e-9)
    assert np.exp(smoothed(factors)) == pytest.approx(exact["marginal"], abs=1e-9)
    assert np.exp(filtered(factors)) == pytest.approx(exact["prefix"], abs=1e-9)
    assert viterbi(factors).tolist() == exact["best"].tolist()
    moments = expectations(factors)
    assert moments.log_z == pytest.approx(exact["log_z"], abs=1e-9)
    assert moments.unary == pytest.approx(exact["marginal"], abs=1e-9)
    assert moments.pairwise == pytest.approx(exact["pairs"], abs=1e-9)
    assert path_score(factors, exact["best"]) == pytest.approx(exact["best_score"])


def enumerated_count_covariance(factors: ChainFactors, row: np.ndarray, n_rows: int) -> np.ndarray:
    """The covariance of the counts (row, class) and (pairwise row, class pair) over every path of every chain."""
    classes = factors.n_classes
    size = n_rows * classes + len(factors.pairwise) * classes ** 2
    bounds = [*np.flatnonzero(factors.link < 0), len(factors.link)]
    covariance = np.zeros((size, size))
    for first, end in zip(bounds[:-1], bounds[1:]):
        paths, scores = enumerate_chain(factors, first, end)
        weights = np.exp(scores - logsumexp(scores))
        counts = np.zeros((len(paths), size))
        for p, path in enumerate(paths):
            for i, t in enumerate(range(first, end)):
                counts[p, row[t] * classes + path[i]] += 1
                if i:
                    counts[p, n_rows * classes + (factors.link[t] * classes + path[i - 1]) * classes + path[i]] += 1
        mean = weights @ counts
        covariance += (counts * weights[:, None]).T @ counts - np.outer(mean, mean)
    return covariance


@pytest.mark.parametrize("seed", range(10))
def test_count_covariance_matches_enumeration(seed: int) -> None:
    """The Hessian of log Z with unary log-potentials shared by the frames of a row: every chain length, cuts,
    forbidden transitions, one or several pairwise rows."""
    rng = np.random.default_rng(100 + seed)
    factors = random_factors(rng, int(rng.integers(1, 8)), int(rng.integers(2, 4)), rows=1 + seed % 3,
                             forbid=0.15 if seed % 2 else 0.0)
    if not np.isfinite(brute_force(factors)["log_z"]):
        pytest.skip("this draw has a chain with no possible path")
    row = rng.integers(0, 3, size=len(factors.link))
    exact = enumerated_count_covariance(factors, row, 3)
    assert count_covariance(factors, row, 3) == pytest.approx(exact, abs=1e-10)


def test_count_covariance_of_long_chains_adds_up_across_blocks() -> None:
    """Long chains run as blocks side by side: the same numbers as a chain cut into its independent pieces."""
    rng = np.random.default_rng(7)
    pieces = [random_factors(rng, size, 3, rows=2, cuts=0.0) for size in (1500, 7, 800)]
    joined = ChainFactors(np.concatenate([p.unary for p in pieces]), np.concatenate([p.pairwise for p in pieces]),
                          np.concatenate([np.where(p.link < 0, -1, p.link + 2 * k) for k, p in enumerate(pieces)]))
    rows = [rng.integers(0, 4, size=len(p.link)) for p in pieces]
    whole = count_covariance(joined, np.concatenate(rows), 4)
    size, unary = 4 * 3 + 6 * 9, 4 * 3
    parts = np.zeros((size, size))
    for k, (piece, row) in enumerate(zip(pieces, rows)):
        part = count_covariance(piece, row, 4)  # its own pairwise rows 0, 1 sit at 2k, 2k + 1 in the joined chain
        at = np.r_[np.arange(unary), unary + 18 * k + np.arange(18)]
        parts[np.ix_(at, at)] += part
    assert np.abs(whole - parts).max() < 1e-8 * np.abs(parts).max()
    short = count_covariance(pieces[1], rows[1], 4)
    assert short == pytest.approx(enumerated_count_covariance(pieces[1], rows[1], 4), abs=1e-10)


def test_count_covariance_over_many_chains_is_found_in_pieces_of_whole_chains(monkeypatch) -> None:
    """Beyond CHUNK_FRAMES frames the chains are taken a piece of whole chains at a time (the scratch memory bounded
    by the piece): the covariance of all of them at once, a chain longer than a piece alone in its piece."""
    from mlnseq.mln import chain_moments

    rng = np.random.default_rng(11)
    factors = random_factors(rng, 3000, 3, rows=2, cuts=0.02)
    row = rng.integers(0, 4, size=len(factors.link))
    whole = count_covariance(factors, row, 4)
    monkeypatch.setattr(chain_moments, "CHUNK_FRAMES", 300)
    pieces = chain_moments._pieces(factors.link)
    assert len(pieces) > 5 and [p.start for p in pieces[1:]] == [p.stop for p in pieces[:-1]]
    assert all(factors.link[p.start] < 0 for p in pieces)
    assert np.abs(count_covariance(factors, row, 4) - whole).max() < 1e-10 * np.abs(whole).max()


@pytest.mark.parametrize("seed", range(6))
def test_repeated_steps_give_the_same_numbers(seed: int) -> None:
    """Frames sharing a unary row (a few rows, long runs and odd lengths, cuts, forbidden transitions): the scan that
    computes each distinct product once agrees with the plain one, and with enumeration on short chains."""
    rng = np.random.default_rng(200 + seed)
    frames = [5, 6, 7, 1000, 3001, 4096][seed]
    n_rows, classes = 4, 3
    rows = rng.normal(size=(n_rows, classes)) * 2
    rows[rng.random(rows.shape) < 0.1] = -np.inf
    rows[:, 0] = np.maximum(rows[:, 0], 0.0)  # every row allows some class
    row = np.repeat(rng.integers(0, n_rows, size=frames), rng.integers(1, 6, size=frames))[:frames]
    base = random_factors(rng, frames, classes, rows=2, forbid=0.1 if seed % 2 else 0.0, cuts=0.01)
    factors = ChainFactors(rows[row], base.pairwise, base.link)
    repeats = Repeats.of(row, factors.link)
    assert frames < 1000 or repeats.levels  # long runs of few rows: products repeat
    plain, repeated = expectations(factors), expectations(factors, repeats)
    assert repeated.log_z == pytest.approx(plain.log_z, rel=1e-12)
    assert np.abs(repeated.unary - plain.unary).max() < 1e-10
    assert np.abs(repeated.pairwise - plain.pairwise).max() < 1e-8 * max(1.0, np.abs(plain.pairwise).max())
    covariance = count_covariance(factors, row, n_rows, repeats)
    assert np.abs(covariance - count_covariance(factors, row, n_rows)).max() < 1e-8 * np.abs(covariance).max()
    if frames < 8 and np.isfinite(brute_force(factors)["log_z"]):
        assert repeated.unary == pytest.approx(brute_force(factors)["marginal"], abs=1e-9)


def test_path_score_is_the_log_potential_of_the_path() -> None:
    factors = random_factors(np.random.default_rng(1), 5, 3, cuts=0.0)
    paths, scores = enumerate_chain(factors, 0, 5)
    for path, score in zip(paths[::17], scores[::17]):
        assert path_score(factors, np.array(path)) == pytest.approx(score)


def test_filtering_is_online() -> None:
    """Frame t's filtered distribution does not change when anything after t changes."""
    rng = np.random.default_rng(2)
    factors = random_factors(rng, 3000, 5, rows=3, forbid=0.1, cuts=0.002)
    before = filtered(factors)
    changed_unary, changed_link = factors.unary.copy(), factors.link.copy()
    changed_unary[1700:] = rng.normal(size=(1300, 5)) * 3
    changed_link[1700:] = rng.integers(-1, 3, size=1300)
    after = filtered(ChainFactors(changed_unary, factors.pairwise, changed_link))
    assert np.array_equal(before[:1700], after[:1700]) or np.abs(before[:1700] - after[:1700]).max() < 1e-12
    assert np.abs(before[1700:] - after[1700:]).max() > 0.1


def test_filter_steps_give_the_batch_numbers() -> None:
    rng = np.random.default_rng(3)
    factors = random_factors(rng, 5000, 6, rows=4, forbid=0.2, cuts=0.01)
    online = Filter(6)
    steps = np.array([online.step(u, None if link < 0 else factors.pairwise[link])
                      for u, link in zip(factors.unary, factors.link)])
    batch = filtered(factors)
    finite = np.isfinite(batch)
    assert np.array_equal(finite, np.isfinite(steps))
    assert np.abs(batch[finite] - steps[finite]).max() < 1e-9
    online.reset()
    assert online.step(factors.unary[7], factors.pairwise[0]) == pytest.approx(
        factors.unary[7] - logsumexp(factors.unary[7]))  # after reset the next frame starts a chain


def test_a_cut_makes_independent_chains() -> None:
    rng = np.random.default_rng(4)
    first, second = random_factors(rng, 400, 4, cuts=0.0), random_factors(rng, 300, 4, cuts=0.0)
    joined = ChainFactors(np.concatenate([first.unary, second.unary]),
                          np.concatenate([first.pairwise, second.pairwise]),
                          np.concatenate([first.link, np.where(second.link < 0, -1, second.link + 2)]))
    assert log_partition(joined) == pytest.approx(log_partition(first) + log_partition(second), abs=1e-8)
    assert np.abs(smoothed(joined) - np.concatenate([smoothed(first), smoothed(second)])).max() < 1e-9
    assert viterbi(joined).tolist() == viterbi(first).tolist() + viterbi(second).tolist()


def test_chain_starts_follow_episodes_and_splits() -> None:
    episode = np.array([0, 0, 0, 1, 1, 2])
    split = np.array(["train", "train", "test", "test", "test", "test"])
    assert chain_starts(episode).tolist() == [True, False, False, True, False, True]
    assert chain_starts(episode, split).tolist() == [True, False, True, True, False, True]
    # some rows alone: a chain also starts after a gap (rows 1 and 4 left out), and a mask is the same as its indices
    rows = np.array([0, 2, 3, 5])
    assert chain_starts(episode, rows=rows).tolist() == [True, True, True, True]
    assert chain_starts(episode, split, rows=np.isin(np.arange(6), [0, 1, 4])).tolist() == [True, False, True]
    assert chain_starts(episode, rows=[3, 4]).tolist() == [True, False]


def test_hard_constraints_remove_transitions() -> None:
    rng = np.random.default_rng(5)
    factors = random_factors(rng, 2000, 4, rows=1, cuts=0.0)
    pairwise = factors.pairwise.copy()
    pairwise[0, 0, 1] = pairwise[0, 2, 3] = -np.inf  # forbidden: 0 -> 1 and 2 -> 3
    constrained = ChainFactors(factors.unary, pairwise, factors.link)
    path = viterbi(constrained)
    steps = set(zip(path[:-1].tolist(), path[1:].tolist()))
    assert (0, 1) not in steps and (2, 3) not in steps
    moments = expectations(constrained)
    assert moments.pairwise[0, 0, 1] == 0.0 and moments.pairwise[0, 2, 3] == 0.0
    assert moments.pairwise.sum() == pytest.approx(1999)


def test_dead_ends_restart_the_chain_in_batch_and_online() -> None:
    """A frame no class can reach restarts from its unary; an all -inf unary becomes uniform; never NaN."""
    unary = np.array([[0.0, -np.inf, -np.inf],   # class 0 only
                      [0.5, 0.2, -0.3],
                      [-np.inf, -np.inf, 1.0],   # class 2 only, but 0 -> 2 and 1 -> 2 are forbidden
                      [0.1, 0.2, 0.3],
                      [-np.inf, -np.inf, -np.inf],  # nothing possible at all
                      [0.3, -0.1, 0.0]])
    pairwise = np.zeros((1, 3, 3))
    pairwise[0, 0, 2] = pairwise[0, 1, 2] = -np.inf
    pairwise[0, 2, 1] = -np.inf
    factors = ChainFactors(unary, pairwise, np.array([-1, 0, 0, 0, 0, 0]))
    batch = filtered(factors)
    assert not np.isnan(batch).any() and not np.isnan(smoothed(factors)).any()
    assert np.exp(batch[2]) == pytest.approx([0.0, 0.0, 1.0])  # restarted from its unary alone
    assert np.exp(batch[4]) == pytest.approx([1 / 3] * 3)  # uniform
    assert np.exp(batch[3]).tolist()[1] == 0.0  # 2 -> 1 stays forbidden after the restart
    online = Filter(3)
    steps = np.array([online.step(u, None if t == 0 else pairwise[0]) for t, u in enumerate(unary)])
    assert np.allclose(np.exp(steps), np.exp(batch), atol=1e-12)
    path = viterbi(factors)
    assert path[0] == 0 and path[2] == 2 and path[3] != 1
    pieces = [(0, 2), (2, 4), (4, 6)]  # the chain as cut by its dead ends
    cut = sum(log_partition(ChainFactors(np.where(np.isfinite(unary[a:b]).any(axis=1, keepdims=True), unary[a:b], 0.0),
                                         pairwise, np.r_[-1, np.zeros(b - a - 1, dtype=int)])) for a, b in pieces)
    assert log_partition(factors) == pytest.approx(cut)


def test_dead_ends_with_repeated_steps_restart_as_without() -> None:
    rows = np.array([[0.0, -np.inf, -np.inf], [-np.inf, -np.inf, 0.5]])  # class 0 only; class 2 only
    pairwise = np.zeros((1, 3, 3))
    pairwise[0, 0, 2] = -np.inf  # so every switch from the first row to the second is a dead end
    row = np.tile([0, 0, 1, 1], 8)
    factors = ChainFactors(rows[row], pairwise, np.r_[-1, np.zeros(len(row) - 1, dtype=np.int64)])
    repeats = Repeats.of(row, factors.link)
    assert repeats.levels
    plain, repeated = expectations(factors), expectations(factors, repeats)
    assert repeated.log_z == pytest.approx(plain.log_z) and np.allclose(repeated.unary, plain.unary)
    assert np.allclose(count_covariance(factors, row, 2, repeats), count_covariance(factors, row, 2))


def test_bad_factors_are_refused() -> None:
    with pytest.raises(ValueError, match="frame 0"):
        ChainFactors(np.zeros((2, 2)), np.zeros((1, 2, 2)), np.array([0, 0]))
    with pytest.raises(ValueError, match="finite or -inf"):
        ChainFactors(np.array([[np.nan, 0.0]]), np.zeros((1, 2, 2)), np.array([-1]))
    with pytest.raises(ValueError, match="shapes"):
        ChainFactors(np.zeros((2, 3)), np.zeros((1, 2, 2)), np.array([-1, 0]))
    empty = ChainFactors(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64))
    assert filtered(empty).shape == (0, 3) and viterbi(empty).shape == (0,) and log_partition(empty) == 0.0


def test_chains_whose_block_products_underflow_decode_as_the_filter_does(own_data_glitch) -> None:
    """The own-data MLN over its twelve trials read as one chain, its frame factors sharpened threefold (a surer
    model): probabilities of the states the order's hard rules keep reachable fall below e^-745 within a block,
    though the filter, normalising every frame, keeps them; decoding goes on and agrees with it frame by frame."""
    from dataclasses import replace

    import polars as pl

    from mlnseq.catalog import artifacts
    from mlnseq.binarize import binarize
    from mlnseq.mln import chain
    from mlnseq.recognition.recognizer import Recognizer

    recognizer = Recognizer.load(own_data_glitch["model"])
    features = pl.read_csv(own_data_glitch["csv"]).select(recognizer.features).to_numpy()
    n = len(features)
    keys = {"episode": np.zeros(n, dtype=np.int64), "frame": np.arange(n), "label": np.zeros(n), "split": np.full(n, "test")}
    frames = artifacts.frames_table(keys, {name: features[:, i] for i, name in enumerate(recognizer.features)})
    evidence = binarize(frames, recognizer.spec).select(recognizer.columns).to_numpy().astype(bool)
    factors = recognizer.mln.chain(evidence, chain.chain_starts(keys["episode"]))
    factors = replace(factors, unary=3 * factors.unary)
    live = chain.Filter(factors.n_classes)
    online, restarted = [], []
    for t, (unary, link) in enumerate(zip(factors.unary, factors.link)):
        online.append(live.step(unary, None if link < 0 else factors.pairwise[link]))
        restarted += [t] * live.restarted
    decoded = chain.decode_filter(factors)
    assert np.abs(np.exp(online) - decoded.probabilities).max() < 1e-9 and decoded.restarts.tolist() == restarted
    assert np.array_equal(np.exp(chain.filtered(factors)), decoded.probabilities)
    offline = chain.decode_viterbi(factors)
    assert np.isfinite(chain.log_partition(factors))
    assert np.allclose(offline.probabilities.sum(axis=1), 1.0) and np.array_equal(offline.restarts, decoded.restarts)
    assert np.isfinite(chain.path_score(replace(factors, link=np.where(np.isin(np.arange(n), decoded.restarts), -1,
                                                                             factors.link)), offline.path))
