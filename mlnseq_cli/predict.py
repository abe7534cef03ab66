"""`mlnseq predict`: recognise new recordings with a model file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from mlnseq_cli.console import console, reported_errors
from stages import predict as stage
from stages.table_import import TableColumns


def predict(
    model: Annotated[Path, typer.Argument(help="A model file written by `mlnseq export`.", dir_okay=False)],
    source: Annotated[Path, typer.Option(help="A CSV or Parquet file, or a folder of them (one episode each), with the model's feature columns.")],
    output: Annotated[Optional[Path], typer.Option("--output", "-o", help="The predictions file \\[default: SOURCE-NAME.predictions.parquet here].", dir_okay=False)] = None,
    decode: Annotated[Optional[str], typer.Option(help="none, filter or viterbi \\[default: the model's]; viterbi decodes a filter model offline.")] = None,
    label_column: Annotated[str, typer.Option(help="The label column, if the recordings have one: then the metrics are printed and stored too.")] = "label",
    episode_column: Annotated[Optional[str], typer.Option(help="The episode column \\[default: 'episode' if present, else one episode per file].")] = None,
    time_column: Annotated[Optional[str], typer.Option(help="The time/frame column, rising within an episode \\[default: 'frame' if present, else file order].")] = None,
) -> None:
    """Read MODEL and the recordings at SOURCE (as `collect --env table` reads them); write per frame its episode, frame, label (if any), class and every class's probability (p_CLASS) to a Parquet file, and, when the recordings are labelled, the eval metrics (printed, and kept in the file's metadata)."""
    options = stage.PredictOptions(model=model, source=source, output=output, decode=decode,
                                   columns=TableColumns(label=label_column, episode=episode_column, time=time_column))
    with reported_errors():
        result = stage.run(options)
    from stages.recognizer import restart_note

    restarted = ""
    if result.restarts:
        console.print(f"[yellow]note[/]: {restart_note('predict', result.restarts)}")
        restarted = f", {len(result.restarts)} chain restart{'s' * (len(result.restarts) != 1)}"
    console.print(f"[green]predict[/]: wrote {result.path} ({result.table.height:,} frames, {result.episodes} episodes{restarted})")
    if result.metrics is not None:
        m = result.metrics
        table = Table("segments", "frames", "macro F1", "edit", "F1@10", "F1@25", "F1@50", box=None,
                      title="labelled recordings: segment recognised at half of its frames")
        table.add_row(f"{m['segment_accuracy']:.1%}", f"{m['frame_accuracy']:.1%}", f"{m['macro_f1']:.3f}",
                      *(f"{m[k]:.1f}" for k in ("edit", "f1@10", "f1@25", "f1@50")))
        console.print(table)
