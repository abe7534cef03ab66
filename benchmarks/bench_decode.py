"""Chain decoding speed: online filtering's added cost per frame, and filtered / smoothed / Viterbi over all
DESK test frames, with the MLN factors of examples/temporal.mln learned (cll) on the DESK training split.

Online: ``Filter.step`` on precomputed factors (the filter's own cost per frame; target < 0.05 ms), and
the whole live path per frame (the MLN factors of one frame from their cache, then the step). Also
``Filter.step`` with 10 classes. Batch: the three decoders over the 20,924 test frames (one chain), the
median of a few runs, and per frame. Lagged and legal decoders (issue 24): per frame online, and batch, with
the check that both give the same classes; and every decoding ``conflate --decode all`` scores, at once. Data:
the authors' published DESK motion codes (paper predicates). ``BENCH_QUICK=1``: the first 4,000 test frames, each
timing once.
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq import learn_weights
from mlnseq.formulas import formulas_for, read_spec
from mlnseq.mln import chain
from mlnseq.mln.factors import MLNFactors
from mlnseq.mln.published_codes import desk_predicates

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
TEMPORAL = Path(__file__).resolve().parents[1] / "examples" / "temporal.mln"
TARGET_STEP_MS = 0.05
QUICK = os.environ.get("BENCH_QUICK") == "1"
REPEATS = 1 if QUICK else 3
QUICK_FRAMES = 4_000


def desk_factors() -> tuple[pl.DataFrame, list[str], np.ndarray, np.ndarray]:
    """The learned weights, the predicate columns, and the test frames' evidence and chain starts."""
    table = desk_predicates(DATA)[0]
    columns = artifacts.feature_columns(table)
    mln = read_spec(TEMPORAL)
    formulas_for(mln, TEMPORAL, columns, [f"S{k + 1}" for k in range(7)])
    weights = learn_weights.learn(table, 7, mln).weights
    test = table.filter(pl.col("split") == "test")
    return weights, columns, test.select(columns).to_numpy(), chain.chain_starts(test["episode"].to_numpy())


def per_step_ms(unary: np.ndarray, pairwise: np.ndarray, link: np.ndarray) -> float:
    online = chain.Filter(unary.shape[1])
    started = time.perf_counter()
    for row, joined in zip(unary, link):
        online.step(row, None if joined < 0 else pairwise[joined])
    return (time.perf_counter() - started) / len(unary) * 1000


def main() -> None:
    weights, columns, evidence, starts = desk_factors()
    if QUICK:
        evidence, starts = evidence[:QUICK_FRAMES], starts[:QUICK_FRAMES]
    factors = MLNFactors.from_weights(weights, columns, 7).chain(evidence, starts)
    frames = len(evidence)
    step_ms = statistics.median(per_step_ms(factors.unary, factors.pairwise, factors.link) for _ in range(REPEATS))
    verdict = "meets" if step_ms < TARGET_STEP_MS else "MISSES"
    print(f"decode: Filter.step on the MLN factors, {frames:,} DESK test frames: {step_ms * 1000:.1f} us per frame "
          f"({verdict} the {TARGET_STEP_MS * 1000:.0f} us target, {TARGET_STEP_MS / step_ms:.1f}x under it)", flush=True)

    mln = MLNFactors.from_weights(weights, columns, 7)  # an empty cache, as a live stream starts with
    online = chain.Filter(7)
    started = time.perf_counter()
    for t, row in enumerate(evidence):
        unary = mln.unary(row[None])[0]
        pairwise = None if starts[t] else mln.pairwise(evidence[t - 1][None], row[None])[0]
        online.step(unary, pairwise)
    live_ms = (time.perf_counter() - started) / frames * 1000
    print(f"decode: live path (MLN factors of the frame from the cache + Filter.step): {live_ms * 1000:.1f} us per frame")

    rng = np.random.default_rng(0)
    wide = rng.normal(size=(5000, 10)), rng.normal(size=(1, 10, 10)), np.r_[-1, np.zeros(4999, dtype=np.int64)]
    wide_ms = statistics.median(per_step_ms(*wide) for _ in range(REPEATS))
    print(f"decode: Filter.step with 10 classes: {wide_ms * 1000:.1f} us per frame")

    for name, decode in (("filtered", chain.filtered), ("smoothed", chain.smoothed), ("viterbi", chain.viterbi),
                         ("log_partition", chain.log_partition)):
        times = []
        for _ in range(REPEATS):
            started = time.perf_counter()
            decode(factors)
            times.append(time.perf_counter() - started)
        seconds = statistics.median(times)
        print(f"decode: {name:13s} over {'the first' if QUICK else 'all'} {frames:,} DESK test frames: "
              f"{seconds * 1000:7.1f} ms ({seconds / frames * 1e6:.2f} us per frame)", flush=True)
    started = time.perf_counter()
    batch = chain.filtered(factors)
    batch_s = time.perf_counter() - started
    print(f"decode: batch filtered is {step_ms * frames / 1000 / batch_s:.0f}x faster than stepping the filter "
          f"frame by frame (same numbers: max |diff| "
          f"{np.abs(batch[-1] - stepped_last(factors)).max():.1e} on the last frame)")
    lagged(factors)


def lagged(factors: chain.ChainFactors) -> None:
    """Issue 24: the lagged and legal decoders one frame at a time (lag_online.Online, per frame) and over the whole
    recording at once (lag.decode), on the same DESK test chain; the two give the same classes."""
    from mlnseq.catalog.decoders import DEFAULT_LAGS, Decoder, decodings, parse_decoding
    from mlnseq.mln import lag, lag_online

    for name in ("filter-legal", "smooth@10", "smooth-legal@25", "lagviterbi@1", "lagviterbi-legal@25"):
        decoding = parse_decoding(name)
        online, out, times = lag_online.Online(factors.n_classes, decoding), [], []
        for row, joined in zip(factors.unary, factors.link):
            started = time.perf_counter()
            out += online.step(row, None if joined < 0 else factors.pairwise[joined])
            times.append(time.perf_counter() - started)
        out += online.finish()
        started = time.perf_counter()
        batch = lag.decode(factors, decoding)
        batch_s = time.perf_counter() - started
        same = np.array_equal([f.label for f in out], batch.path)
        print(f"decode: {name:20s} online median {statistics.median(times) * 1e6:6.1f} us, p99 "
              f"{np.percentile(times, 99) * 1e6:6.1f} us per frame; batch {batch_s * 1000:6.1f} ms over "
              f"{len(times):,} frames; same classes: {same}", flush=True)
    every = [d for d in decodings(tuple(Decoder), DEFAULT_LAGS) if d.decoder not in (Decoder.FILTER, Decoder.VITERBI)]
    times = []
    for _ in range(REPEATS):
        started = time.perf_counter()
        lag.decode_all(factors, every)
        times.append(time.perf_counter() - started)
    print(f"decode: the {len(every)} lagged, posterior and legal decodings `conflate --decode all` scores (lags "
          f"{', '.join(map(str, DEFAULT_LAGS))}), at once over the {len(factors.link):,} frames: "
          f"{statistics.median(times) * 1000:.0f} ms (median of {REPEATS})", flush=True)


def stepped_last(factors: chain.ChainFactors) -> np.ndarray:
    online = chain.Filter(factors.n_classes)
    for row, joined in zip(factors.unary, factors.link):
        last = online.step(row, None if joined < 0 else factors.pairwise[joined])
    return last


if __name__ == "__main__":
    main()
