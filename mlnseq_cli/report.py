"""`mlnseq report`: the paper's tables and figures from a `make reproduce` run."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from mlnseq_cli.console import console, counted, reported_errors
from mlnseq import report as stage


def report(
    runs: Annotated[Path, typer.Option(help="The run folder of `make reproduce` (its RUNS).", file_okay=False)] = stage.ReportOptions.runs,
    out: Annotated[Path, typer.Option(help="Folder to write REPORT.md and its figures into.", file_okay=False)] = stage.ReportOptions.out,
) -> None:
    """Read RUNS/DATASET/{frames,predicates,weights}.parquet, RUNS/DATASET/MODE/seed-N/{metrics.parquet, models/*.log.parquet} and RUNS/timings.tsv; write OUT/REPORT.md (Table III paper vs mlnseq, Table IV, learned weights, data efficiency, stream mode, timings, hyper-parameters, differences from the paper) and its PNG figures beside it."""
    options = stage.ReportOptions(runs=runs, out=out)
    with reported_errors():
        with console.status(f"reading {runs} and drawing figures"):
            result = stage.run(options)
    console.print(
        f"[green]report[/]: wrote {result.path} ({counted(len(result.figures), 'figure')}; datasets "
        f"{', '.join(result.datasets)}, {counted(result.n_seed_runs, 'seed run')})"
    )
