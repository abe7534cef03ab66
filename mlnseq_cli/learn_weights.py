"""`mlnseq learn-weights`: learn the formulas' weights on the training split."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table
from rich.markup import escape

from mlnseq_cli.console import DEFAULT, WorkdirOption, console, counted, reported_errors
from mlnseq.catalog import artifacts


def learn_weights(
    formulas: Annotated[Path, typer.Argument(help="The .mln file: relative to the current folder, else to the workdir.")] = Path(artifacts.FORMULAS),
    engine: Annotated[str, typer.Option(help="native (vectorised) or pracmln (the paper's engine, slow; pll only).")] = "native",
    objective: Annotated[Optional[str], typer.Option(
        help="pll (pracmln's pseudo-likelihood) or cll (exact conditional likelihood of each episode's classes); "
             "default: cll when a formula uses Next, else pll.", show_default=False)] = None,
    l2: Annotated[Optional[float], typer.Option(
        help="L2 penalty (Gaussian prior) on the learned weights; default: 0 for pll, 0.1 for cll.",
        show_default=False)] = None,
    folds: Annotated[int, typer.Option(
        help="K >= 2: also learn each of K folds' weights without that fold, for cross-validation "
             "(the folds of `train --folds K`); 0: none.")] = 0,
    max_formulas: Annotated[int, typer.Option(
        help="Refuse formulas whose templates and variables expand to more ground formulas than this.")] = 20_000,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """Read WORKDIR/predicates.parquet (training split) and FORMULAS; write WORKDIR/weights.parquet and WORKDIR/learned.mln (with --folds K also WORKDIR/weights.folds.parquet, each fold's weights learned without it)."""
    from mlnseq import learn_weights as stage  # the engine's scipy loads when the command runs, not for --help
    from mlnseq.mln.weights_table import strongest, strongest_temporal

    options = stage.LearnWeightsOptions(formulas=formulas, engine=engine, objective=objective, l2=l2, folds=folds,
                                        max_formulas=max_formulas)
    with reported_errors():
        options.validate()
        path, learned = stage.run(workdir, options)
    for warning in learned.warnings:
        console.print(f"[yellow]warning[/]: {escape(warning)}")  # a warning may hold [..]: not markup
    table = Table(title="strongest formulas per class")
    for column in ("class", "weight", "formula"):
        table.add_column(column, justify="right" if column == "weight" else "left")
    for row in strongest(learned.weights).iter_rows(named=True):
        weight = "hard" if row["hard"] else f"{row['weight']:.3f}" + (" (fixed)" if row["fixed"] else "")
        table.add_row(row["class"], weight, row["formula"])
    console.print(table)
    transitions = strongest_temporal(learned.weights)
    if transitions.height:
        table = Table(title="temporal formulas: hard, then the strongest")
        table.add_column("weight", justify="right")
        table.add_column("formula")
        for row in transitions.iter_rows(named=True):
            table.add_row("hard" if row["hard"] else f"{row['weight']:.3f}", row["formula"])
        console.print(table)
    also = ""
    if folds:
        from mlnseq.choosing.folds import MOST_FOLDS, describe

        meta = artifacts.read_metadata(path.parent / artifacts.FOLD_WEIGHTS, "fold_weights")
        record, episodes = meta["folds"], meta.get("training_episodes", 0)
        across = (f", across episodes: the training split has {episodes} and `--folds {min(episodes, MOST_FOLDS)}` cuts whole "
                  "ones;" if record["kind"] == "blocks" and episodes >= 2 else ";")
        also = f", and {artifacts.FOLD_WEIGHTS} ({describe(record)}{across} each fold's weights learned without it)"
    console.print(f"[green]learn-weights[/] ({engine}, {learned.objective}, l2 {learned.l2:g}): wrote {path} "
                  f"({counted(learned.weights.height, 'formula')}) and {artifacts.LEARNED_MLN}{also}")
