"""Training speed: one batched epoch of `mlnseq train` against a batch-size-1, segment-by-segment loop
of the same model (the authors' loop: a tensor built from Python lists per segment, one SGD step per
segment, torch's default threads), on the DESK training split and on a Fetch collection; the ratio is
reported, not judged (the earlier 20x target is retired: a small LSTM's batch-1 step is already cheap on a
CPU). Beside it, cross-validation's cost: `train --mode stream` of one network against the same with
``--folds 5`` (the network refit on the whole training split plus 5 fold networks, in one process), on
DESK; and networks fitted side by side (one batched network, as `train` fits fold networks and several seeds)
against one after another: the 5 fold networks of a TCN and of an LSTM, and 5 LSTM seeds in segment mode.
Per-frame streaming recognition: bench_recognize.

``BENCH_FETCH_EPISODES`` sets the Fetch collection's size (all of it used as training frames); ``BENCH_QUICK=1``:
each timing once, and 2 epochs where 20 are timed (for tests/test_benchmarks.py).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import torch

from mlnseq import collect, train
from mlnseq.timeline import sequences
from mlnseq.networks import fitting
from mlnseq.choosing import training_rows as rows
from mlnseq.networks.classifier import SequenceClassifier
from mlnseq.networks.recurrent import Config as ModelConfig

DESK_SOURCE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "desk-taurus"
QUICK = os.environ.get("BENCH_QUICK") == "1"
REPEATS = 1 if QUICK else 3
EPOCHS = 2 if QUICK else 20  # of the fold networks and seeds timed


def baseline_epoch(model: SequenceClassifier, segments: list[tuple[list, list]]) -> float:
    """The authors' loop: one segment at a time, tensors from Python lists, one step each."""
    optimizer = torch.optim.SGD(model.parameters(), lr=0.1)
    loss_function = torch.nn.NLLLoss()
    started = time.perf_counter()
    for features, labels in segments:
        model.zero_grad()
        x = torch.tensor(features, dtype=torch.float).view(1, len(features), -1)
        y = torch.tensor(labels, dtype=torch.long)
        loss = loss_function(model(x)[0][0], y)
        loss.backward()
        optimizer.step()
    return time.perf_counter() - started


def batched_epoch(data: train.FrameData, options: train.TrainOptions) -> float:
    """One epoch of :func:`train.fit` without its per-epoch evaluation (timed from the log-free path)."""
    parts, fit_units, _ = rows.assign_parts(data, options)
    features = ((data.features - data.features.mean(0)) / (data.features.std(0) + 1e-8)).astype(np.float32)
    model = SequenceClassifier(ModelConfig(features.shape[1], int(data.labels.max()) + 1))
    parameters = list(model.parameters())
    started = time.perf_counter()
    x_all = torch.from_numpy(sequences.pad(fit_units, features))
    y_all = torch.from_numpy(sequences.pad(fit_units, data.labels, fill=-100))
    n_all = torch.as_tensor(sequences.lengths(fit_units))
    order = np.random.default_rng(0).permutation(len(fit_units))
    for start in range(0, len(order), options.batch_size):
        index = torch.as_tensor(order[start : start + options.batch_size])
        longest = int(n_all[index].max())
        log_probs = model(x_all[index, :longest])[0]
        y = y_all[index, :longest]
        loss = (fitting.frame_losses(log_probs, y).sum(1) / n_all[index]).mean()
        fitting.descend(parameters, loss, options.training.rate)
    return time.perf_counter() - started


def compare(name: str, data: train.FrameData) -> None:
    options = train.TrainOptions()
    train_rows = data.splits == "train"
    spans = [s for s in sequences.segments(data.episodes, data.splits, data.labels) if train_rows[s.start]]
    scaled = (data.features - data.features.mean(0)) / (data.features.std(0) + 1e-8)
    segments = [(scaled[s].tolist(), data.labels[s].tolist()) for s in spans]
    config = ModelConfig(data.features.shape[1], int(data.labels.max()) + 1)

    default_threads = os.cpu_count() or 1  # torch's default; mlnseq itself pins one thread (stages/__init__)
    torch.set_num_threads(default_threads)
    base_default = min(baseline_epoch(SequenceClassifier(config), segments) for _ in range(REPEATS))
    fitting.set_threads()
    base_one = min(baseline_epoch(SequenceClassifier(config), segments) for _ in range(REPEATS))
    ours = min(batched_epoch(data, options) for _ in range(REPEATS))
    wide = train.TrainOptions(batch_size=16)
    ours_wide = min(batched_epoch(data, wide) for _ in range(REPEATS))
    ratio = base_default / ours
    print(f"{name}: {len(spans)} training segments, {int(train_rows.sum()):,} frames; one epoch: "
          f"baseline batch 1 {base_default * 1000:.0f} ms ({default_threads} threads) / "
          f"{base_one * 1000:.0f} ms (1 thread), batched (batch {options.batch_size}, 1 thread) "
          f"{ours * 1000:.0f} ms")
    print(f"{name}: {ratio:.1f}x faster than the authors'-style loop "
          f"({base_one / ours:.1f}x against the same loop on 1 thread; batch 16: {ours_wide * 1000:.0f} ms, "
          f"{base_one / ours_wide:.1f}x)")


def fold_training(frames_path: Path, epochs: int = EPOCHS) -> None:
    """`train --mode stream` with no folds against --folds 5, on the same frames, timed side by side."""
    import shutil
    import tempfile

    seconds = {}
    with tempfile.TemporaryDirectory() as folder:
        shutil.copy(frames_path, Path(folder) / "frames.parquet")
        for k in (0, 5):
            started = time.perf_counter()
            train.run(Path(folder), train.TrainOptions(mode="stream", epochs=epochs, folds=k))
            seconds[k] = time.perf_counter() - started
    print(f"desk: stream training, {epochs} epochs: one network {seconds[0]:.1f} s; the network and 5 fold "
          f"networks (--folds 5) {seconds[5]:.1f} s ({seconds[5] / seconds[0]:.1f}x one network's time)")


def side_by_side(data: train.FrameData, epochs: int = EPOCHS) -> None:
    """Networks fitted one after another against side by side (fitting.fit_together), the same networks from the same
    start, timed alternately: the 5 fold networks of `train --mode stream --folds 5` (TCN and LSTM), and 5 seeds of
    `train --mode segment --seed 0 ... --seed 4`."""
    from dataclasses import replace

    from mlnseq import networks
    from mlnseq.choosing import folds as folding

    folds = folding.assign(data.episodes, data.splits, data.labels, 5)
    for cell, mode in (("tcn", "stream"), ("lstm", "stream"), ("lstm", "segment")):
        options = train.TrainOptions(mode=mode, cell=cell, epochs=epochs)
        config = networks.make_config(cell, n_features=data.features.shape[1], n_classes=int(data.labels.max()) + 1)
        if mode == "stream":
            what = "5 fold networks"
            runs = [(replace(data, splits=folds.splits(k)), options) for k in range(folds.k)]
        else:
            what = "5 seeds"
            runs = [(data, replace(options, seed=seed)) for seed in range(5)]

        def started() -> list[fitting.Fitting]:
            return [rows.Rows.of(d, o).start(d, config, o, torch.device("cpu")) for d, o in runs]

        seconds: dict[str, list[float]] = {"one after another": [], "side by side": []}
        for _ in range(REPEATS):
            fittings = started()
            begun = time.perf_counter()
            for one in fittings:
                for _ in range(epochs):
                    one.epoch(options.batch_size, options.training.rate)
            seconds["one after another"].append(time.perf_counter() - begun)
            fittings = started()
            begun = time.perf_counter()
            fitting.fit_together(fittings, epochs, options.batch_size, options.training.rate)
            seconds["side by side"].append(time.perf_counter() - begun)
        alone, together = (min(values) for values in seconds.values())
        print(f"desk: {cell} {mode} mode, {what}, {epochs} epochs (best of {REPEATS}): one after another "
              f"{alone:.2f} s, side by side {together:.2f} s ({alone / together:.1f}x)")


def main() -> None:
    import tempfile

    desk = collect.collect(collect.CollectOptions(env="desk", source=DESK_SOURCE)).frames
    desk_data = train.FrameData.from_frames(desk)
    compare("desk", desk_data)
    fitting.set_threads()
    side_by_side(desk_data)
    with tempfile.TemporaryDirectory() as folder:
        collect.run(Path(folder), collect.CollectOptions(env="desk", source=DESK_SOURCE))
        fold_training(Path(folder) / "frames.parquet")
    episodes = int(os.environ.get("BENCH_FETCH_EPISODES", "20"))
    try:
        fetch = collect.collect(collect.CollectOptions(env="fetch", episodes=episodes, seed=0,
                                                       train_frames=episodes * 50)).frames
    except Exception as error:  # MuJoCo absent or broken: DESK figures still stand
        print(f"fetch: skipped ({type(error).__name__}: {error})")
    else:
        compare(f"fetch ({episodes} episodes)", train.FrameData.from_frames(fetch))


if __name__ == "__main__":
    main()
