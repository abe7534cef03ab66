"""`mlnseq stream`: recognise live frames from stdin, one JSON line out per frame."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from mlnseq_cli.console import fail, reported_errors
from mlnseq import stream as stage
from mlnseq.catalog.stopping import Stopped


def stream(
    model: Annotated[Path, typer.Argument(help="A model file written by `mlnseq export`.", dir_okay=False)],
    strict: Annotated[bool, typer.Option(help="Stop at the first bad input line (exit 2) instead of skipping it.")] = False,
    max_line_bytes: Annotated[int, typer.Option(
        help="The longest input line read; a longer one is counted, not held, and reported and skipped.")] = stage.MAX_LINE_BYTES,
    max_hold: Annotated[Optional[float], typer.Option(help="`rostopic echo -p`: the longest a frame holds the feed's last row, in seconds (inf: no bound); past it the frames are skipped, with a note \\[default: the model's].")] = None,
    explain: Annotated[int, typer.Option(help="Add \"why\" to each line: the N largest terms of its frame's margin (kind, text, line, contribution; docs/explain.md); off by default.")] = 0,
    decode: Annotated[Optional[str], typer.Option(help="A decoder, with @LAG for smooth and lagviterbi (e.g. smooth-legal@5), \\[default: the model's]; viterbi or posterior need a whole recording: live, the filter decodes with the same factors, and a note says so.")] = None,
    monitor: Annotated[bool, typer.Option("--monitor", help="Audit each recording as it goes (docs/audit.md): the moment one turns suspect, a JSON line with an \"alert\" key (the reason in words, its episode, the time, the phase, since which frame, and why: its measure against the allowance), after the frame lines answered with it; nothing for recordings that stay ok.")] = False,
) -> None:
    """Read frames from stdin, one per line: JSON objects of feature name -> value (an "episode" key, when its value changes, starts a new episode), or CSV rows after a header line. Or `rostopic echo -p TOPIC` for a model trained on one ROS topic: its rows are put on the model's clock as collect put the bags on it. Write one JSON line per frame as soon as it is decided: {"episode", "frame", "class", "probabilities", "lag"} (and "time" and "stamp" where the input has them; `rostopic echo -p` rows: time from the first message, stamp on the messages' clock; --explain N: "why"); with a lag L, frame t once frame t + L has arrived, the frames read together before the stream waits for more. A bad line (text before the first JSON frame and a line over --max-line-bytes too) is reported on stderr with its number and skipped (--strict: exit 2). SIGINT (Ctrl-C) or SIGTERM: every frame read so far is decided and answered, then exit 130 or 143."""
    options = stage.StreamOptions(model=model, strict=strict, max_line_bytes=max_line_bytes, max_hold=max_hold,
                                  explain=explain, decode=decode, monitor=monitor)

    def emit(line: str) -> None:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()

    def warn(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    with reported_errors():
        try:
            stage.run(options, sys.stdin.buffer, emit, warn)
        except Stopped as stopped:  # SIGINT 130, SIGTERM 143
            what = "interrupted" if stopped.signum == signal.SIGINT else f"stopped by {stopped.name}"
            raise fail(f"{what}; every frame read so far was answered", stopped.exit_code) from None
        except BrokenPipeError:  # the reader went away (e.g. `| head`): nothing is left to answer
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python's own advice for SIGPIPE
