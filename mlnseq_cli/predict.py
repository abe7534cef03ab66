"""`mlnseq predict`: recognise new recordings with a model file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.table import Table

from mlnseq_cli import source_options as read_as
from mlnseq_cli.console import console, counted, reported_errors
from mlnseq import predict as stage


def scored(metrics: dict) -> str:
    """Which recordings the metrics score: every one, or the labelled ones of them."""
    if metrics["recordings"] == metrics["of"]:
        return "labelled recordings"
    return f"{counted(metrics['recordings'], 'labelled recording')} of {metrics['of']}"


@read_as.reads_recordings
def predict(
    model: Annotated[Path, typer.Argument(help="A model file written by `mlnseq export`.", dir_okay=False)],
    source: Annotated[Path, typer.Option(help="The new recordings, in the form the model's were read (a CSV/Parquet file or folder, a bag, a dataset...).")],
    output: Annotated[Optional[Path], typer.Option("--output", "-o", help="The predictions file \\[default: the source's name + .predictions.parquet, in the current folder].", dir_okay=False)] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite the output files if they exist.")] = False,
    intervals: Annotated[Optional[Path], typer.Option(help="Also write the predicted segments as episode, start, end, label rows (the form --labels reads).", dir_okay=False)] = None,
    rerun: Annotated[Optional[Path], typer.Option(help="Also write a Rerun recording (.rrd) of features, true and predicted class and probabilities, and the segments as time ranges (needs rerun-sdk).", dir_okay=False)] = None,
    write_lerobot: Annotated[Optional[Path], typer.Option(help="lerobot (v3.0): also write a copy of the dataset to this new folder with the predicted phases as LeRobot's subtask annotations (language_persistent rows of style subtask), everything else as it was; episodes annotated already keep theirs.")] = None,
    write_lerobot_probabilities: Annotated[bool, typer.Option("--write-lerobot-probabilities", help="With --write-lerobot: the class probabilities as a per-frame feature too (docs/lerobot.md names it).")] = False,
    replace_subtasks: Annotated[bool, typer.Option("--replace-subtasks", help="With --write-lerobot: write the predicted subtasks over the episodes' own annotations too.")] = False,
    explain: Annotated[int, typer.Option(help="Explain every frame: a why column of its N largest terms (JSON: kind, text, line, contribution; docs/explain.md), and each segment's why (what held it, what ended it) in --intervals and --rerun.")] = 0,
    **reading: Any,
) -> None:
    """Read MODEL and the recordings at SOURCE, read as the model's own recordings were (env, episode, time and label columns, topics, rate: the model remembers them; options override); write per frame its episode (the recording's own id), frame, label (if any), class and every class's probability (p_CLASS) to a Parquet file, and, when the recordings are labelled, the eval metrics (printed, and kept in the file's metadata). With --write-lerobot OUT, a LeRobot dataset comes back as a copy holding the predicted phases as its own subtask annotations, which `collect --labels subtask` and LeRobot read. An existing output is kept unless --force."""
    options = stage.PredictOptions(
        model=model, source=source, output=output, force=force, intervals=intervals, rerun=rerun,
        write_lerobot=write_lerobot, lerobot_probabilities=write_lerobot_probabilities,
        replace_subtasks=replace_subtasks, explain=explain, reading=read_as.read_options(**reading))
    with reported_errors():
        result = stage.run(options)
    from mlnseq.fusion.fuse import restart_note

    for note in result.notes:
        console.print(f"note: {note}", markup=False, highlight=False)
    restarted = ""
    if result.restarts:
        console.print(f"[yellow]note[/]: {restart_note('predict', result.restarts)}")
        restarted = f", {counted(len(result.restarts), 'chain restart')}"
    console.print(f"[green]predict[/]: wrote {result.path} ({counted(result.table.height, 'frame')}, "
                  f"{counted(result.episodes, 'episode')}{restarted})")
    for path in result.written:
        console.print(f"[green]predict[/]: wrote {path}")
    if result.lerobot is not None:
        kept = f"; {counted(result.lerobot.kept, 'episode')} kept their own" if result.lerobot.kept else ""
        console.print(f"[green]predict[/]: subtasks of {counted(result.lerobot.predicted, 'episode')} written as LeRobot "
                      f"annotations (language_persistent, style subtask){kept}", highlight=False)
    if result.metrics is not None:
        m = result.metrics
        table = Table("segments", "frames", "macro F1 (segments)", "edit", "F1@10", "F1@25", "F1@50", box=None,
                      title=f"{scored(m)}: segment recognised at half of its frames")
        table.add_row(f"{m['segment_accuracy']:.1%}", f"{m['frame_accuracy']:.1%}", f"{m['macro_f1']:.3f}",
                      *(f"{m[k]:.1f}" for k in ("edit", "f1@10", "f1@25", "f1@50")))
        console.print(table)

