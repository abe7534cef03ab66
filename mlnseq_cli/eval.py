"""`mlnseq eval`: score the predictions on the test split (the paper's segment metric and more)."""

from __future__ import annotations

import json
from typing import Annotated

import typer
from rich.measure import Measurement
from rich.table import Table

from mlnseq_cli.headings import legend, short_names
from mlnseq_cli.console import DEFAULT, WorkdirOption, console, reported_errors
from mlnseq import eval as stage
from mlnseq.timeline.metrics import EARLY_FRACTIONS


def evaluate(
    method: Annotated[str, typer.Option(help="network (the network alone; also lstm), mln, priorlayer, conflation, "
                                             "combined (each optionally +filter or +viterbi, as conflate --decode made "
                                             "them) or all.")] = stage.EvalOptions.method,
    fraction: Annotated[float, typer.Option(help="Recognise each segment at frame max(int(len*F)-1, 0), 0 < F <= 1 "
                                                 "(the paper: 0.5).")] = stage.EvalOptions.fraction,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object keyed by method instead of "
                                                         "tables.")] = False,
    tables: Annotated[bool, typer.Option(help="Print the summary, per-class and early-recognition tables; "
                                              "--no-tables: only the line naming what was written (make reproduce: "
                                              "the report reads metrics.parquet).")] = True,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """Read WORKDIR/predictions.parquet; write WORKDIR/metrics.parquet (method, metric, item, value): segment accuracy
    at the fraction, per-class and early-recognition accuracy, frame accuracy, macro F1 over segments (per-class F1
    of the segments recognised at the fraction, averaged over the classes), confusion and, without segment
    boundaries, edit score and F1@10/25/50."""
    options = stage.EvalOptions(method=method, fraction=fraction)
    with reported_errors():
        result = stage.run(workdir, options)
    if as_json:
        print(json.dumps({m: {**r, "per_class": {result.classes[k]: v for k, v in r["per_class"].items()},
                              "early": {str(f): v for f, v in r["early"].items()}, "mode": result.modes[m]}
                          for m, r in result.results.items()}))
        return
    if tables:
        print_tables(result, fraction)
    console.print(f"[green]eval[/]: wrote {result.path}")


def print_tables(result: stage.EvalResult, fraction: float) -> None:
    """The summary, per-class and early-recognition tables, a row per method, readable at 80 columns."""
    def table(title: str, *columns: str) -> Table:
        shown = Table(title=title, box=None, padding=(0, 1), collapse_padding=True, pad_edge=False, title_justify="left")
        shown.add_column("method", no_wrap=True)
        for column in columns:
            shown.add_column(column, justify="right", no_wrap=True)
        return shown

    for with_mode in (True, False):  # too wide for the terminal with the mode column: without it, and a note
        summary = table(f"test split: segment recognised at {fraction:g} of its frames; mF1: macro F1 over segments",
                        *(["mode"] if with_mode else []), "segment", "frame", "mF1", "edit", "F1@10", "F1@25", "F1@50")
        summary.columns[1].justify = "left" if with_mode else "right"
        for method_name, r in result.results.items():
            extra = [f"{r[k]:.1f}" if k in r else "-" for k in ("edit", "f1@10", "f1@25", "f1@50")]
            summary.add_row(method_name, *([result.modes[method_name]] if with_mode else []),
                            f"{r['segment_accuracy']:.1%}", f"{r['frame_accuracy']:.1%}", f"{r['macro_f1']:.3f}",
                            *extra)
        if Measurement.get(console, console.options.update_width(10_000), summary).maximum <= console.width:
            break
    console.print(summary)
    if not with_mode:
        modes = sorted(set(result.modes.values()))
        console.print(f"(mode, {' or '.join(modes)}, left out at {console.width} columns; --json shows it)",
                      highlight=False)
    widest = max(map(len, result.results), default=0)  # the method column, then a column per class
    headings = short_names(list(result.classes), room=max(console.width - widest - 1, 20))
    per_class = table("segment accuracy per class (%)", *headings)
    for method_name, r in result.results.items():
        per_class.add_row(method_name, *(f"{100 * r['per_class'][k]:.0f}" for k in range(len(result.classes))))
    console.print(per_class)
    for line in legend(headings, list(result.classes)):
        console.print(line, highlight=False)
    early = table("early recognition: segment accuracy (%) at a fraction of each segment",
                  *(f"{f:g}" for f in EARLY_FRACTIONS))
    for method_name, r in result.results.items():
        early.add_row(method_name, *(f"{100 * v:.0f}" for v in r["early"].values()))
    console.print(early)
