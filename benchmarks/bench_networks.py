"""Per-frame streaming cost of every registered network type (stages/networks/), side by side in one run.

Each type is built at the DESK shape (3 features, 7 classes, 32 hidden units or channels, with the PriorLayer)
with seeded random weights (the cost does not depend on their values), then run in numpy as the recogniser
runs it: ``StreamingNetwork.step`` over 20,000 frames (p50 and p99 per frame), and ``Network.log_probs`` over
the same frames as one recording (per frame). The ratio to the LSTM is printed, not judged.
``BENCH_QUICK=1`` runs 5,000 frames.
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np


def build(cell: str):
    import torch

    from mlnseq import networks
    from mlnseq.networks.classifier import SequenceClassifier
    from mlnseq.networks.network import Network

    torch.manual_seed(0)
    config = networks.make_config(cell, n_features=3, n_classes=7, hidden_size=32, prior_layer=True)
    model = SequenceClassifier(config)
    return Network.from_state(config.to_dict(), {k: v.numpy() for k, v in model.state_dict().items()},
                              np.zeros(3, dtype=np.float32), np.ones(3, dtype=np.float32))


def main() -> None:
    from mlnseq import networks
    from mlnseq.networks.network import StreamingNetwork

    n_frames = 5_000 if os.environ.get("BENCH_QUICK") else 20_000
    rng = np.random.default_rng(0)
    features, prior = rng.normal(size=(n_frames, 3)), rng.normal(size=(n_frames, 7))
    measured = {}
    for cell in networks.CELLS:
        network = build(cell)
        stream = StreamingNetwork(network)
        times = []
        for x, p in zip(features, prior):
            started = time.perf_counter()
            stream.step(x, p)
            times.append(time.perf_counter() - started)
        started = time.perf_counter()
        network.log_probs([slice(0, n_frames)], features, prior)
        whole = (time.perf_counter() - started) / n_frames
        measured[cell] = statistics.median(times), float(np.percentile(times, 99)), whole
    base = measured["lstm"]
    for cell, (p50, p99, whole) in measured.items():
        print(f"{cell:5s} ({networks.describe(build(cell).config)}): step p50 {p50 * 1e6:.1f} µs "
              f"({p50 / base[0]:.2f}x the LSTM's), p99 {p99 * 1e6:.1f} µs; whole recording {whole * 1e6:.2f} µs "
              f"per frame ({whole / base[2]:.2f}x) over {n_frames:,} frames", flush=True)
