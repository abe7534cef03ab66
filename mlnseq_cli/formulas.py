"""`mlnseq formulas`: write the domain knowledge as WORKDIR/formulas.mln."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from mlnseq_cli.console import DEFAULT, WorkdirOption, console, counted, reported_errors
from mlnseq import formulas as stage
from mlnseq.mln.grounding import is_template


def formulas(
    spec: Annotated[Optional[Path], typer.Option(help="A .mln file of formulas and `+var` templates \\[default: the built-in stages/specs/paper.mln, the paper's Has(+w,p) => Topic(+c,p)].")] = None,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """Read WORKDIR/predicates.parquet and the spec; write WORKDIR/formulas.mln (pracmln syntax, templates kept)."""
    options = stage.FormulasOptions(spec=spec)
    with reported_errors():
        written = stage.run(workdir, options)
    templates = sum(1 for f in written.mln.formulas if is_template(f.formula))
    console.print(
        f"[green]formulas[/]: wrote {written.path} ({counted(len(written.mln.formulas), 'formula')} of which "
        f"{templates} with +variables; training shows {counted(len(written.words), 'predicate value')} and "
        f"{counted(len(written.classes), 'class', 'classes')})"
    )
