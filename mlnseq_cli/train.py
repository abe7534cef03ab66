"""`mlnseq train`: fit a network (LSTM, GRU or causal TCN), alone or with the MLN PriorLayer."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import polars as pl
import typer
from rich.markup import escape

from mlnseq_cli.console import DEFAULT, console, counted, reported_errors
from mlnseq_cli.progress import FOLD_NETWORKS, epoch_progress
from mlnseq import networks
from mlnseq import train as stage
from mlnseq.choosing.folds import out_of_fold_said

Defaults = stage.TrainOptions
HELP = {
    "seed": "Seed of initial weights and batch order; one per --workdir when several are given.",
    "workdir": "Folder holding this dataset's artifacts. Several (each with its --seed, in order): the seed workdirs "
               "of one dataset, whose networks are fitted side by side (1.4-1.9x as fast for 5 LSTMs); their "
               "inputs must be the same files.",
    "method": "network: the network alone, of any --cell (also written lstm, its name in the workdir: "
              "models/lstm.pt); or priorlayer: the network with the MLN's PriorLayer input (needs predicates.parquet "
              "and weights.parquet).",
    "mode": "segment: each true segment is a sequence (the paper); stream: whole episodes, no boundaries.",
    "cell": f"Network type: {', '.join(networks.CELLS)} (tcn: a causal temporal convolutional network).",
    "prior": "priorlayer's MLN input: paper (clamped weight sums, as the authors) or logprob (MLN log-probabilities).",
    "select": "none: train on every training sequence, keep the last epoch; last: hold out the last 20% of them as a "
              "validation part (conflate chooses its weights there), keep the last epoch; val_accuracy: hold it out, "
              "keep the best epoch on it.",
    "measure": "After which epochs the train, val and test parts are measured over all their frames and logged "
               "(models/METHOD.log.parquet): every-epoch (the per-epoch curves; a pass over every frame after each "
               "epoch) or last-epoch (the kept network only). Default: every-epoch with --select val_accuracy, which "
               "needs it, else last-epoch.",
    "folds": "Cross-validation: also train K networks, each without one fold of the training split (whole episodes, "
             "else contiguous blocks), and write their out-of-fold predictions of every training frame "
             "(models/METHOD.oof.parquet), on which conflate learns the network factor's weight and chooses. Default: "
             "in stream mode with --select none, the K of the MLN's fold weights when `mlnseq learn-weights --folds "
             "K` wrote them, else 0 (none).",
    "smoothing": "tcn: weight of MS-TCN's truncated-MSE smoothing loss (MS-TCN uses 0.15); 0: none.",
    "optimizer": "sgd: plain SGD at a fixed rate for --epochs, the last kept (the authors'); averaged (fit's) or adam: "
                 "SGD's or Adam's steps over a budget of updates, their moving average kept; with folds, the fold "
                 "networks train first and the network stops where their out-of-fold predictions score best.",
    "members": "Networks trained side by side per seed, merged into one that predicts their mean; fit trains 3.",
    "updates": "averaged and adam: at most this many updates (--batch-size sequences each); 0: --epochs alone decide.",
    "paper_floor": "How the authors' code made the MLN's per-class sums non-negative (PriorLayer's paper input, "
                   "conflate's mln-mode paper): clamp (negative sums to 0, their DESK code) or shift (by each frame's "
                   "minimum, their Fetch code). Default: shift for --env fetch recordings, else clamp. Recorded in the "
                   "checkpoint.",
}


def train(
    method: Annotated[str, typer.Option(help=HELP["method"])] = "network",
    seed: Annotated[list[int], typer.Option(help=HELP["seed"])] = [Defaults.seed],
    epochs: Annotated[int, typer.Option(help="Passes over the training sequences.")] = Defaults.epochs,
    mode: Annotated[str, typer.Option(help=HELP["mode"])] = Defaults.mode,
    cell: Annotated[str, typer.Option(help=HELP["cell"])] = Defaults.cell,
    prior: Annotated[str, typer.Option(help=HELP["prior"])] = Defaults.prior.value,
    select: Annotated[str, typer.Option(help=HELP["select"])] = Defaults.select.value,
    measure: Annotated[Optional[str], typer.Option(help=HELP["measure"], show_default=False)] = None,
    folds: Annotated[Optional[int], typer.Option(help=HELP["folds"], show_default=False)] = None,
    device: Annotated[str, typer.Option(help="auto (cuda when present), cpu or cuda.")] = Defaults.device,
    train_fraction: Annotated[float, typer.Option(help="Train on the first F of the training sequences, "
                                                       "0 < F <= 1.")] = Defaults.train_fraction,
    batch_size: Annotated[int, typer.Option(help="Sequences per update.")] = Defaults.batch_size,
    window: Annotated[int, typer.Option(help="stream mode: training window length in frames.")] = Defaults.window,
    smoothing: Annotated[float, typer.Option(help=HELP["smoothing"])] = Defaults.smoothing,
    optimizer: Annotated[str, typer.Option(help=HELP["optimizer"])] = Defaults.optimizer.value,
    members: Annotated[int, typer.Option(help=HELP["members"])] = Defaults.members,
    updates: Annotated[int, typer.Option(help=HELP["updates"])] = Defaults.updates,
    paper_floor: Annotated[Optional[str], typer.Option(help=HELP["paper_floor"], show_default=False)] = None,
    workdir: Annotated[list[Path], typer.Option("--workdir", "-w", help=HELP["workdir"], file_okay=False)] = [DEFAULT],
) -> None:
    """Read WORKDIR/frames.parquet (priorlayer: also predicates.parquet and weights.parquet); write
    WORKDIR/models/METHOD.pt (the network with its configuration) and WORKDIR/models/METHOD.log.parquet (epoch,
    split, accuracy, loss: after the last epoch, or every epoch with --measure every-epoch)."""
    options = stage.TrainOptions(method=method, seed=seed[0], epochs=epochs, mode=mode, cell=cell, prior=prior,
                                 select=select, measure=measure, folds=folds, device=device, window=window,
                                 train_fraction=train_fraction, batch_size=batch_size, smoothing=smoothing,
                                 paper_floor=paper_floor, optimizer=optimizer, members=members, updates=updates)
    with reported_errors():
        options.validate()
        what = options.cell if options.method == "lstm" else str(options.method)  # the network alone: its cell
        seeds = f", seeds {', '.join(map(str, seed))} side by side" if len(seed) > 1 else ""
        with epoch_progress(f"{what} ({mode} mode{seeds})" + _then_folds(workdir[0], options), epochs) as progress:
            results = stage.run_seeds(workdir, tuple(seed), options, progress)
    for result in results:
        trained = result.trained
        for warning in trained.warnings:
            console.print(f"[yellow]warning[/]: {escape(warning)}")  # a warning may hold [..]: not markup
        last = trained.log.filter(pl.col("epoch") == trained.kept_epoch)
        shown = ", ".join(f"{row['split']} {row['accuracy']:.1%}" for row in last.iter_rows(named=True))
        console.print(
            f"[green]train[/]: wrote {result.checkpoint} ({what}, {counted(trained.n_train_units, 'training sequence')}, "
            f"kept epoch {trained.kept_epoch}, frame accuracy {shown}; {result.device}) and {result.log}"
            + out_of_fold_said(result.checkpoint, folds is not None))


def _then_folds(workdir, options: stage.TrainOptions) -> str:
    """What trains after the bar's epochs: K fold networks (asked for, or as learn-weights cut them), or nothing."""
    from mlnseq.choosing.folds import train_folds

    k = train_folds(options.folds, options.mode, options.select, workdir)
    then = f", then {k} {FOLD_NETWORKS}" if options.optimizer == "sgd" else \
        f", stopped where its {k} networks without a fold score best on it (those first)"
    return then if k else ""
