"""`mlnseq binarize`: turn frames into boolean predicates."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from mlnseq_cli.headings import legend, short_names
from mlnseq_cli.console import DEFAULT, WorkdirOption, console, counted, fail, reported_errors
from mlnseq import binarize as stage
from mlnseq.catalog import artifacts



def binarize(
    spec: Annotated[Optional[Path], typer.Option(help="Predicate spec (TOML) \\[default: the built-in spec of the frames' source, stages/specs/<source>.binarize.toml].", dir_okay=False)] = None,
    suggest: Annotated[bool, typer.Option("--suggest", help="Learn a spec from these frames' training split (per channel a level, a change over a window or a gripper, thresholds by decision stumps, kept by cross-validation on the folds `mlnseq fit` cuts) and formulas for it (conjunctions of two predicates where they help), each commented; write them to --output and NAME.formulas.mln beside it; then binarize with the spec.")] = False,
    output: Annotated[Optional[Path], typer.Option("--output", "-o", help="--suggest: the spec file to write \\[default: WORKDIR/learned.binarize.toml]; one edited by hand is kept unless --force.", dir_okay=False)] = None,
    force: Annotated[bool, typer.Option("--force", help="--suggest: overwrite --output even if edited by hand.")] = False,
    table: Annotated[bool, typer.Option("--table", help="Also print each predicate value's share of frames true, overall and per class (training split), and which values mark each class: help for writing formulas. Without --spec or --suggest, of the workdir's predicates as they are (nothing rewritten).")] = False,
    max_columns: Annotated[int, typer.Option(help="Refuse a spec that makes more predicate columns than this (a pair makes one per combination).")] = stage.BinarizeOptions.max_columns,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """Read WORKDIR/frames.parquet and a predicate spec (--spec, the source's built-in one, or --suggest: one written from the frames); write WORKDIR/predicates.parquet (episode, frame, label, split, then one boolean column per predicate value, named <predicate>_<value>)."""
    if output is not None and not suggest:
        raise fail("--output names the spec --suggest writes: add --suggest", 2)
    if table and spec is None and not suggest:
        with reported_errors():  # the workdir's predicates as they are: nothing rewritten, nothing after made stale
            existing = stage.as_it_is(workdir)
        if existing is not None:
            console.print(f"binarize: {existing.path} as it is (spec {existing.meta['spec']['path']}); --spec FILE "
                          "binarizes again", highlight=False)
            print_class_table(existing.predicates, existing.meta["predicates"], list(existing.meta["classes"]))
            return
    suggested = (output or Path(workdir) / artifacts.LEARNED_SPEC) if suggest else None
    options = stage.BinarizeOptions(spec=spec, suggest=suggested, replace=force, max_columns=max_columns)
    with reported_errors():
        path, binarized = stage.run(workdir, options)
    if suggested is not None:
        print_learned(binarized.meta["learned"], suggested)
    columns = binarized.meta["predicates"]
    console.print(
        f"[green]binarize[/]: wrote {path} ({counted(len(columns), 'predicate')}, "
        f"{counted(sum(len(c) for c in columns.values()), 'column')}, {counted(binarized.predicates.height, 'frame')}; "
        f"spec {binarized.meta['spec']['path']})"
    )
    if table:
        print_class_table(binarized.predicates, columns, list(binarized.meta["classes"]))


def print_learned(learned: dict, spec: Path) -> None:
    """What --suggest learned: the search in one line, then its predicates and strongest formulas, one line each (the
    formulas file named beside ``spec``, as it was given)."""
    from mlnseq.learning.learned_files import formulas_path

    found = learned.get("cross_validated") or {}
    how = (f"by {learned['folds']} cross-validation (the MLN alone, {found.get('decoder', 'filter')}: frame accuracy "
           f"{found['frame_accuracy']:.1f} %)" if learned.get("folds") and found else
           "without cross-validation (too few training frames for 2 folds)")
    console.print(f"binarize: learned {counted(len(learned['predicates']), 'predicate')} and "
                  f"{counted(len(learned['conjunctions']), 'conjunction')} of {learned['candidates']} candidates on "
                  f"{counted(learned['channels'], 'channel')} {how}: {spec} and {formulas_path(spec)} (edit them, then "
                  f"--spec {spec} and `mlnseq formulas --spec {formulas_path(spec)}`)", highlight=False)
    for line in learned.get("said", []):
        console.print(f"  {line}", highlight=False)


def print_class_table(predicates, columns: dict[str, list[str]], classes: list[str]) -> None:
    """The predicate values' shares of frames true (all frames, then per class on the training split), readable
    at 80 columns, then the value that most marks each class."""
    from mlnseq.predicates.separation import class_shares

    names = [c for group in columns.values() for c in group]
    shares = class_shares(predicates, names, classes)
    headings = short_names(shares.classes)
    wide = len(headings) <= 8
    shown = Table("column", "true", *(headings if wide else ("most in", "least in")), "spread", box=None,
                  padding=(0, 1), pad_edge=False,
                  title=f"share of frames true: all frames, then % of each class's {shares.frames:,} training frames")
    for i, name in enumerate(names):
        row = shares.shares[i]
        per_class = [f"{100 * v:.0f}" for v in row] if wide else [
            f"{headings[int(row.argmax())]} {100 * row.max():.0f}",
            f"{headings[int(row.argmin())]} {100 * row.min():.0f}"]
        shown.add_row(name, f"{shares.overall[i]:.1%}", *per_class, f"{100 * shares.spread[i]:.0f}")
    for column in shown.columns[1:]:
        column.justify = "right"
    console.print(shown)
    for line in legend(headings, shares.classes):
        console.print(line, highlight=False)
    console.print("marks each class (% of its frames true; for Has(...) => Topic(...)):")
    for k, heading in enumerate(headings):
        column, inside, elsewhere = shares.marker(k)
        said = f"{column} ({inside:.0%}; other classes at most {elsewhere:.0%})" if inside > elsewhere else \
            "none: no value is true in more of its frames than in another class's (a formula cannot single it out)"
        console.print(f"  {heading}: {said}", highlight=False)
