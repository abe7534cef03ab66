"""`mlnseq review`: a model's phases over the recordings' signals in the browser; corrections saved as labels."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from mlnseq_cli import source_options as read_as
from mlnseq_cli.console import counted, reported_errors


@read_as.reads_recordings
def review(
    model: Annotated[Path, typer.Argument(help="A model file written by `mlnseq export` or `mlnseq fit`.", dir_okay=False)],
    source: Annotated[Optional[Path], typer.Option(help="The recordings, read as `predict` reads them (as the model's recordings were read) \\[default: those of -w WORKDIR's fit].")] = None,
    workdir: Annotated[Optional[Path], typer.Option("--workdir", "-w", help="A fit's workdir: its recordings, ranked to label as its label_next.csv ranks them where it has one.", file_okay=False)] = None,
    save: Annotated[Optional[Path], typer.Option(help="The labels file a save writes (episode,start,end,label: what `collect --labels` reads); read back at the start if it exists \\[default: the source's name + .labels.csv here, or WORKDIR.labels.csv beside the workdir].", dir_okay=False)] = None,
    save_lerobot: Annotated[Optional[Path], typer.Option(help="A LeRobot (v3.0) source: each save also writes a copy of the dataset to this folder with the saved labels as the saved episodes' subtask annotations and the model's phases as the others' (their own annotations kept), as `predict --write-lerobot` writes them.", file_okay=False)] = None,
    host: Annotated[str, typer.Option(help="The address to listen on; only this machine reaches the page unless it says otherwise.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="The port (0: any free one).")] = 8750,
    **reading: Any,
) -> None:
    """Read MODEL and the recordings (--source, or -w WORKDIR's), decide each as `explain` does, and serve a page on http://127.0.0.1:PORT/ (printed) until Ctrl+C or SIGTERM: the recordings (id, length, how sure the model is, rank to label); for one, its channels on one time axis, the decided phases as a band with the true labels beneath and disagreements marked, the chosen class's probability; a click explains the frame (the terms of `mlnseq explain --json`). Boundaries are moved, segments relabelled, split and merged with the mouse or the keyboard; a save writes the recording's labels into --save (nothing is written without a save, never into the source). Requests from another site or address are refused; every script the page runs is served from the package."""
    from mlnseq import review as stage

    options = stage.ReviewOptions(model=model, source=source, workdir=workdir, save=save,
                                  save_lerobot=save_lerobot, host=host, port=port,
                                  reading=read_as.read_options(**reading))

    def started(where: stage.Started) -> None:
        print(f"review: {counted(where.recordings, 'recording')} ({counted(where.frames, 'frame')}) at {where.url} "
              f"; saves go to {where.save}; Ctrl+C stops", flush=True)
        if where.reached_from is not None:
            print(f"review: --host {host} listens beyond this machine: {where.reached_from} can open this page, read "
                  "these recordings and save labels (nothing checks who asks); --host 127.0.0.1 keeps it to this "
                  "machine", flush=True)

    with reported_errors():
        stopped = stage.run(options, started, lambda line: print(line, flush=True))
    print(f"review: stopped ({stopped})", flush=True)
