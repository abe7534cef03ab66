"""How the per-recording costs grow with a recording's length: eval (its segment matching and edit score apart),
conflate's per-frame work (the numpy network over every frame, the MLN's class scores, Viterbi decoding) and one
stream-mode training epoch, on one generated recording of 20k, 200k and 2M frames side by side, with the growth
from each length to the next (10x the frames: about 10x is linear, about 100x quadratic).

The recording: DESK's test episode (real features, labels and predicates) repeated into one episode of N frames;
the predictions scored are the MLN alone's (they flicker: many short segments, eval's hardest case). The network
and the MLN weights are trained once on DESK's training split (examples/temporal.mln, 1 epoch). Before issue 29
eval matched every predicted segment against every true one (that matching, kept in the tests as the reference,
is timed beside at the lengths it fits in memory). Training runs windows of 64 frames, 4 a step, as `mlnseq train
--mode stream`; each figure is one run (the slowest take minutes at 2M frames).

``BENCH_LENGTH_FRAMES`` sets the lengths (default ``20000,200000,2000000``).
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DESK_SOURCE = REPO.parent / "shared" / "data" / "desk-taurus"
QUADRATIC_LIMIT = 5e7  # predicted x true segments up to which the old matching runs (its IoU matrices: 8 bytes each)


def _desk_workdir(folder: Path) -> Path:
    """DESK frames, predicates, temporal.mln's weights and a stream LSTM trained 1 epoch."""
    from mlnseq import binarize, collect, formulas, learn_weights, train

    collect.run(folder, collect.CollectOptions(env="desk", source=DESK_SOURCE))
    binarize.run(folder, binarize.BinarizeOptions())
    formulas.run(folder, formulas.FormulasOptions(spec=REPO / "examples" / "temporal.mln"))
    learn_weights.run(folder, learn_weights.LearnWeightsOptions())
    train.run(folder, train.TrainOptions(mode="stream", epochs=1, folds=0))
    return folder


def _timed(work: Callable[[], object]) -> float:
    started = time.perf_counter()
    work()
    return time.perf_counter() - started


def _old_matching(predicted: np.ndarray, truth: np.ndarray) -> None:
    """Eval's segment matching before issue 29: IoU of every predicted segment with every true one, per overlap."""
    from mlnseq.timeline.metrics import OVERLAPS, label_runs

    p = np.array(label_runs(predicted), dtype=np.int64).reshape(-1, 3)
    t = np.array(label_runs(truth), dtype=np.int64).reshape(-1, 3)
    for _ in OVERLAPS:
        intersection = np.minimum(p[:, None, 2], t[None, :, 2]) - np.maximum(p[:, None, 1], t[None, :, 1])
        union = np.maximum(p[:, None, 2], t[None, :, 2]) - np.minimum(p[:, None, 1], t[None, :, 1])
        iou = np.where(p[:, None, 0] == t[None, :, 0], np.maximum(intersection, 0) / union, -1.0)
        iou.argmax(axis=1)


def measure(workdir: Path, n: int) -> dict[str, float | None]:
    """Seconds of each piece of work on a recording of ``n`` frames."""
    import polars as pl

    from mlnseq import networks
    from mlnseq.catalog import artifacts
    from mlnseq.mln import classifier
    from mlnseq.mln.factors import MLNFactors
    from mlnseq.model.checkpoints import load_checkpoint
    from mlnseq.networks.fitting import Fitting, resolve_device
    from mlnseq.fusion.decoding import decode
    from mlnseq.fusion.fuse import chain_of
    from mlnseq.timeline import metrics, sequences

    frames = pl.read_parquet(workdir / artifacts.FRAMES)
    predicates = pl.read_parquet(workdir / artifacts.PREDICATES)
    weights = pl.read_parquet(workdir / artifacts.WEIGHTS)
    classes = artifacts.read_metadata(workdir / artifacts.FRAMES, "frames")["classes"]
    test = np.flatnonzero(frames["split"].to_numpy() == "test")
    rows = pl.Series(np.resize(test, n))
    frames, predicates = frames[rows], predicates[rows]  # one episode of n frames: the test episode repeated
    labels = frames["label"].to_numpy().astype(np.int64)
    features = frames.select(artifacts.feature_columns(frames)).to_numpy().astype(np.float32)
    episodes, starts = np.zeros(n, dtype=np.int64), np.r_[True, np.zeros(n - 1, dtype=bool)]
    columns = artifacts.feature_columns(predicates)
    evidence = predicates.select(columns).to_numpy().astype(bool)
    seconds: dict[str, float | None] = {}

    scores: list[np.ndarray] = []
    seconds["conflate: MLN class scores"] = _timed(
        lambda: scores.append(classifier.class_scores(predicates, weights, classes)))
    predicted = scores[0].argmax(1)
    seconds["eval: every metric (score_method)"] = _timed(
        lambda: metrics.score_method(predicted, labels, episodes, len(classes), 0.5, True))
    seconds["eval: segment matching, 3 overlaps"] = _timed(lambda: metrics.overlap_counts_all(predicted, labels))
    n_pairs = len(metrics.label_runs(predicted)) * len(metrics.label_runs(labels))
    seconds["eval: the old matching (every pair)"] = (
        _timed(lambda: _old_matching(predicted, labels)) if n_pairs <= QUADRATIC_LIMIT else None)
    seconds["eval: edit score"] = _timed(lambda: metrics.edit_score(predicted, labels))

    checkpoint = load_checkpoint(workdir, "lstm")
    log_p: list[np.ndarray] = []
    seconds["conflate: numpy LSTM, every frame"] = _timed(
        lambda: log_p.append(checkpoint.network.log_probs([slice(0, n)], features, None)))
    mln = MLNFactors.from_weights(weights, columns, classes)
    seconds["conflate: Viterbi (conflation)"] = _timed(
        lambda: decode(chain_of("conflation", mln, evidence, starts, log_p[0], 1.0), "viterbi"))

    config = networks.make_config("lstm", n_features=features.shape[1], n_classes=len(classes), hidden_size=32,
                                  prior_layer=False, smoothing=0.0)
    windows = sequences.training_units("stream", episodes, np.full(n, "train"), labels, 64)
    standardised = (features - features.mean(0)) / features.std(0)
    fitting = Fitting.start(config, standardised.astype(np.float32), None, labels, windows, 0, resolve_device("cpu"))
    seconds["train: one stream epoch (windows of 64)"] = _timed(lambda: fitting.epoch(4, 0.1))
    return seconds


def _cell(value: float | None) -> str:
    return "–" if value is None else f"{value:.3f}"


def main() -> None:
    from mlnseq.networks.fitting import set_threads

    set_threads()
    lengths = [int(x) for x in os.environ.get("BENCH_LENGTH_FRAMES", "20000,200000,2000000").split(",")]
    with tempfile.TemporaryDirectory() as folder:
        workdir = _desk_workdir(Path(folder))
        results = {}
        for n in lengths:
            results[n] = measure(workdir, n)
            print(f"  measured {n:,} frames", flush=True)
    names = list(results[lengths[0]])
    header = " | ".join(f"{n:,} frames (s)" for n in lengths)
    growth = " | ".join(f"x{b / a:g} frames" for a, b in zip(lengths, lengths[1:]))
    print(f"| work | {header} | {growth} |")
    print("|---" * (1 + len(lengths) + len(lengths) - 1) + "|")
    for name in names:
        values = [results[n][name] for n in lengths]
        grown = [f"x{b / a:.1f}" if a and b else "–" for a, b in zip(values, values[1:])]
        print(f"| {name} | {' | '.join(map(_cell, values))} | {' | '.join(grown)} |")


if __name__ == "__main__":
    main()
