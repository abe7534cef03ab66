"""`mlnseq audit`: which recordings went wrong, ranked, with the reasons in words."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.table import Table

from mlnseq_cli import source_options as read_as
from mlnseq_cli.console import console, counted, reported_errors

SHOWN = 10  # rows printed


def reads_recordings_undecoded(command):
    """``command`` with the reading flags predict takes, less --decode (audit decodes by the model's chain)."""
    command = read_as.reads_recordings(command)
    signature = command.__signature__
    command.__signature__ = signature.replace(parameters=[p for p in signature.parameters.values()
                                                         if p.name != "decode"])
    return command


@reads_recordings_undecoded
def audit(
    model: Annotated[Path, typer.Argument(help="A model file written by `mlnseq export` or `mlnseq fit`.", dir_okay=False)],
    source: Annotated[Optional[Path], typer.Option(help="The recordings to audit, in the form the model's were read (a CSV/Parquet file or folder, a bag or a folder of them, a LeRobot dataset...).")] = None,
    workdir: Annotated[Optional[Path], typer.Option("--workdir", "-w", help="A fit's workdir: its recordings are audited when no --source is given; a model exported before `mlnseq audit` learns what it needs from it.", file_okay=False)] = None,
    output: Annotated[Optional[Path], typer.Option("--output", "-o", help="The verdicts, .csv or .parquet \\[default: the source's name + .audit.csv, in the current folder].", dir_okay=False)] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite the output if it exists.")] = False,
    explain: Annotated[int, typer.Option(help="Add each reason's N largest terms (as `mlnseq explain` gives them for the decision at its first frame) to the reasons column.")] = 0,
    write_lerobot: Annotated[Optional[Path], typer.Option(help="lerobot (v3.0): also write a copy of the dataset to this new folder with each episode's verdict, score and reasons as columns of meta/episodes (mlnseq_verdict, mlnseq_score, mlnseq_reason, mlnseq_reasons), for LeRobot's episode_filter.")] = None,
    **reading: Any,
) -> None:
    """Read MODEL and the recordings at SOURCE (read as predict reads them), or those of a fit's WORKDIR; decode each whole recording with the model's chain and score it against what the model learned of its labelled recordings: the orders of its phases, how long each lasts at the recording's own pace, the rules that hold throughout a phase, and how likely the chain found them, each within an allowance cross-validation chose on the training recordings. Write one row per recording, the most suspect first: episode, rank, verdict (ok or suspect), score (suspect from 1), reason (the first, in words), phase, where (seconds and frames), reasons (all, as JSON), frames; print the top ones. An existing output is kept unless --force."""
    from mlnseq import audit as stage

    options = stage.AuditOptions(model=model, source=source, workdir=workdir, output=output, force=force,
                                 explain=explain, write_lerobot=write_lerobot, reading=read_as.read_options(**reading))
    with reported_errors():
        result = stage.run(options)
    for note in result.notes:
        console.print(f"[yellow]note[/]: {note}", highlight=False)
    show(result.table)
    suspect = int((result.table["verdict"] == "suspect").sum())
    console.print(f"[green]audit[/]: wrote {result.path} ({counted(result.table.height, 'recording')}, "
                  f"{suspect} suspect)", highlight=False)
    console.print(calibration_line(result.profile), highlight=False)
    if not result.profile.calibration.trusted:
        console.print(f"[yellow]note[/]: {untrusted(result.profile)}", highlight=False)
    if result.lerobot is not None:
        console.print(f"[green]audit[/]: wrote {result.lerobot}: the dataset with mlnseq_verdict, mlnseq_score, "
                      "mlnseq_reason and mlnseq_reasons per episode (LeRobot: episode_filter=lambda ep: "
                      "ep[\"mlnseq_verdict\"] == \"ok\")", highlight=False)


def show(table) -> None:
    """The most suspect rows (all suspect ones up to SHOWN, then ok ones to fill)."""
    rows = Table("rank", "episode", "verdict", "score", "reason", "where", box=None)
    for row in table.head(SHOWN).iter_rows(named=True):
        colour = "red" if row["verdict"] == "suspect" else "green"
        rows.add_row(str(row["rank"]), row["episode"], f"[{colour}]{row['verdict']}[/]", f"{row['score']:.2f}",
                     row["reason"] or "-", row["where"] or "-")
    console.print(rows)
    if table.height > SHOWN:
        console.print(f"... and {table.height - SHOWN} more in the output", highlight=False)


def calibration_line(profile) -> str:
    """How the allowances were chosen and how often a clean recording crossed them in cross-validation."""
    calibration = profile.calibration
    if not calibration.recordings:
        return ("suspect from score 1: the least allowances (too few labelled training recordings to cross-validate "
                "them)")
    how = "cross-validation" if calibration.how == "cross-validation" else "the training recordings in-sample"
    recordings = counted(calibration.recordings, "labelled training recording")
    return (f"suspect from score 1: allowances chosen by {how} on {recordings}; {calibration.flagged} of "
            f"{calibration.recordings} flagged by allowances set without them")


def untrusted(profile) -> str:
    """Why an audit whose decoding is unsure of the phases is not to be trusted."""
    from mlnseq.auditing.profile import TRUSTED

    calibration = profile.calibration
    return (f"the model's decoding gets {calibration.accuracy:.0%} of the training recordings' frames right "
            f"({calibration.how}); below {TRUSTED:.0%} the phases the audit reads off it are too often wrong for its "
            "verdicts to be trusted: label more recordings, or check the model (docs/audit.md, when not to trust it)")
