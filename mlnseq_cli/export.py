"""`mlnseq export`: one model file with all a recogniser needs."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape

from mlnseq_cli.console import DEFAULT, WorkdirOption, console, reported_errors
from mlnseq import export as stage

Defaults = stage.ExportOptions


def export(
    method: Annotated[str, typer.Option(help="network (the network alone, of any cell; also lstm), mln, priorlayer, "
                                             "conflation, combined, or auto: the method, decoder and lag with the "
                                             "best cross-validated figures conflate recorded (needs networks trained "
                                             "with --folds), within --latency or --lag if given, with --decode's "
                                             "decoder if given; or a name as conflate and eval print it "
                                             "(conflation+smooth-legal@25).")] = Defaults.method.value,
    decode: Annotated[str, typer.Option(help="none (per frame), filter (online), smooth or lagviterbi (with --lag), "
                                             "their -legal forms (never a forbidden transition), posterior or viterbi "
                                             "(offline; stream filters); smooth-legal@5 names the lag too.")] = Defaults.decode,
    lag: Annotated[Optional[int], typer.Option(help="Frames a lagged decoder waits (frame t decided once t + LAG has "
                                                    "arrived); with --method auto, the budget.")] = None,
    latency: Annotated[Optional[float], typer.Option(help="The same budget in seconds, where the recordings' frame "
                                                          "rate is known (not DESK: give --lag).")] = None,
    mln_mode: Annotated[str, typer.Option(help="MLN class probabilities: paper or exact (as "
                                               "conflate --mln-mode).")] = Defaults.mln_mode.value,
    output: Annotated[Optional[Path], typer.Option(
        "--output", "-o", help="The model file \\[default: WORKDIR/METHOD[+DECODE].mlnseq].", dir_okay=False)] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing --output file.")] = False,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """Read WORKDIR's frames.parquet, predicates.parquet, weights.parquet and models/*.pt; write one model file
    (.mlnseq) holding the features and their standardisation, the predicate spec, the MLN weights, the network, the
    fusion and decoding (its network factor weight learned on the out-of-fold predictions of networks trained with
    --folds, else chosen on the validation part), the classes and the input digests, for `mlnseq predict`, `mlnseq
    stream` and the Python API."""
    options = stage.ExportOptions(method=method, decode=decode, mln_mode=mln_mode, output=output, force=force,
                                  lag=lag, latency=latency)
    with reported_errors():
        exported = stage.run(workdir, options)
    manifest = exported.manifest
    for note in manifest.notes:
        console.print(f"[yellow]note[/]: {escape(note)}")
    chosen = manifest.chosen_by_cross_validation
    if chosen is not None:
        from mlnseq.choosing.cross_validation import figures_said

        figures = " ".join(figures_said(chosen.figures, chosen.score).split())
        console.print(f"export: --method auto chose {chosen.name} of {len(chosen.candidates)} candidates by "
                      f"{chosen.folds}-fold cross-validation on the training split: {figures}, the criterion; "
                      f"F1@50 {chosen.figures['f1_50']:.1f}", highlight=False)
    weight = manifest.network_weight
    delay = "" if manifest.lag is None else f", lag {manifest.lag} frame(s)" + (
        "" if manifest.latency_s is None else f" = {manifest.latency_s:g} s")
    console.print(f"[green]export[/]: wrote {exported.path} ({manifest.method}, decode {manifest.decode}{delay}"
                  + ("" if weight is None else f", network factor weight {weight:g}") + ")")
