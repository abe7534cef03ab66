"""`mlnseq explain`: why a model decided what it did at a frame of a recording."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from mlnseq_cli import source_options as read_as
from mlnseq_cli.console import reported_errors


@read_as.reads_recordings
def explain(
    model: Annotated[Path, typer.Argument(help="A model file written by `mlnseq export`.", dir_okay=False)],
    source: Annotated[Path, typer.Option(help="The recording, read as `predict` reads it (as the model's recordings were read).")],
    episode: Annotated[Optional[str], typer.Option(help="The episode, by the recording's own id \\[default: its first].")] = None,
    frame: Annotated[Optional[int], typer.Option(help="Explain this frame of the episode (numbered from 0, as predict numbers it).")] = None,
    time: Annotated[Optional[float], typer.Option(help="Explain the frame at this time (the last at or before it): seconds from the recording's start, or for messages their clock (a live line's stamp); a time outside the recording is refused.")] = None,
    segment: Annotated[Optional[int], typer.Option(help="Explain the episode's K-th decided segment (from 0): what held it and what ended it.")] = None,
    versus: Annotated[Optional[str], typer.Option(help="The class to compare with \\[default: the runner-up].")] = None,
    what_if: Annotated[Optional[str], typer.Option("--what-if", help="PREDICATE=VALUE (e.g. left_gripper=closed, or a column =true/false): score the frame again with it and say whether the decision flips.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines: frame, time, class, versus, margin and terms (kind, text, line, contribution).")] = False,
    **reading: Any,
) -> None:
    """Read MODEL and the recording at SOURCE, decide it as predict does, and print why the frame (--frame T or --time S) got its class: its margin over the runner-up (or --versus CLASS), the log-ratio of their scores, as terms that add up to it exactly: each formula (its text, line, weight and truth for both classes), the network (its weight x its log-probability difference), the start distribution, the frames before and, for lagged and offline decoders, after (the chain's messages), and the hard rules that removed classes. --segment K: the terms that held the K-th segment and the transition that ended it. Sorted by size, the small ones summed in one line; --json writes JSON lines instead."""
    from mlnseq import explain as stage
    from mlnseq.explaining import text as explanation_text

    options = stage.ExplainOptions(model=model, source=source, episode=episode, frame=frame, time=time,
                                   segment=segment, versus=versus, what_if=what_if,
                                   reading=read_as.read_options(**reading))
    with reported_errors():
        found = stage.run(options)
    if as_json:
        records = [found.segment.record()] if found.segment is not None else [found.explanation.record()]
        if found.what_if is not None:
            records.append({"what_if": found.change.text, "flips": found.flips, **found.what_if.record()})
        for record in records:
            print(json.dumps(record))
        return
    if found.episodes > 1 and episode is None:
        print(f"(episode {found.episode}, the first of {found.episodes}; --episode chooses another)")
    if found.segment is not None:
        print("\n".join(explanation_text.segment_table(found.segment)))
        return
    print("\n".join(explanation_text.table(found.explanation)))
    if found.what_if is not None:
        was, now = found.explanation, found.what_if
        verdict = (f"the decision flips: {was.chosen} -> {now.chosen}" if found.flips
                   else f"the decision stays {now.chosen}")
        print(f"\nwhat if {found.change.text}? {verdict}")
        print("\n".join(explanation_text.table(now)))

