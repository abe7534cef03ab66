"""`mlnseq conflate`: run every trained model and the MLN classifier on all frames and combine them."""

from __future__ import annotations

from typing import Annotated

import typer

from mlnseq_cli.console import DEFAULT, WorkdirOption, console, reported_errors
from stages import conflate as stage


def conflate(
    mln_mode: Annotated[str, typer.Option(help="MLN class probabilities: paper (the authors' normalised clamped sums) or exact (softmax of the scores).")] = stage.ConflateOptions.mln_mode,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """Read WORKDIR/frames.parquet, models/*.pt, predicates.parquet and weights.parquet; write WORKDIR/predictions.parquet (keys, then per method METHOD_pred and METHOD_p0.. class probabilities for lstm, mln, priorlayer, conflation = lstm+MLN and combined = priorlayer+MLN, eq. 16)."""
    options = stage.ConflateOptions(mln_mode=mln_mode)
    with reported_errors():
        result = stage.run(workdir, options)
    for note in result.notes:
        console.print(f"[yellow]note[/]: {note}")
    console.print(f"[green]conflate[/]: wrote {result.path} ({', '.join(result.methods)})")
