"""`mlnseq info`: what a model file holds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from mlnseq_cli.console import console, reported_errors


def info(
    model: Annotated[Path, typer.Argument(help="A model file written by `mlnseq export`.", dir_okay=False)],
    as_json: Annotated[bool, typer.Option("--json", help="Print the manifest as JSON.")] = False,
) -> None:
    """Read MODEL (.mlnseq); print its method and decoding, classes, features, network, MLN formulas, notes, the mlnseq
    version that wrote it and the digests of the workdir files it came from."""
    from mlnseq import info as info_stage

    with reported_errors():
        described = info_stage.run(model)
    manifest = described.manifest
    if as_json:
        print(json.dumps(manifest.to_dict(), indent=1, sort_keys=True))
        return
    table = Table(title=f"{model}", box=None, show_header=False)
    for name, value in described.rows:
        table.add_row(name, escape(value))
    console.print(table)
    for note in manifest.notes:
        console.print(f"[yellow]note[/]: {escape(note)}")
