"""`mlnseq binarize`: turn frames into boolean predicates."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from mlnseq_cli.console import DEFAULT, WorkdirOption, console, counted, reported_errors
from mlnseq import binarize as stage


def binarize(
    spec: Annotated[Optional[Path], typer.Option(help="Predicate spec (TOML) \\[default: the built-in spec of the frames' source, stages/specs/<source>.binarize.toml].", dir_okay=False)] = None,
    table: Annotated[bool, typer.Option("--table", help="Also print each predicate value's share of frames true.")] = False,
    max_columns: Annotated[int, typer.Option(help="Refuse a spec that makes more predicate columns than this (a pair makes one per combination).")] = stage.BinarizeOptions.max_columns,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """Read WORKDIR/frames.parquet and a predicate spec; write WORKDIR/predicates.parquet (episode, frame, label, split, then one boolean column per predicate value, named <predicate>_<value>)."""
    options = stage.BinarizeOptions(spec=spec, max_columns=max_columns)
    with reported_errors():
        path, binarized = stage.run(workdir, options)
    columns = binarized.meta["predicates"]
    console.print(
        f"[green]binarize[/]: wrote {path} ({counted(len(columns), 'predicate')}, "
        f"{counted(sum(len(c) for c in columns.values()), 'column')}, {counted(binarized.predicates.height, 'frame')}; "
        f"spec {binarized.meta['spec']['path']})"
    )
    if table:
        shown = Table("predicate", "column", "true", box=None)
        for name, column, share in stage.true_shares(binarized.predicates, columns):
            shown.add_row(name, column, f"{share:.1%}")
        console.print(shown)
