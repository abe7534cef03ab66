"""`mlnseq echo`: a ROS 2 topic's messages as `rostopic echo -p` rows, for `mlnseq stream`."""

from __future__ import annotations

import os
import sys
from typing import Annotated, Optional

import typer

from mlnseq_cli.console import counted, reported_errors
from mlnseq import echo as stage


def echo(
    topic: Annotated[str, typer.Argument(help="The ROS 2 topic, e.g. /joint_states.")],
    count: Annotated[Optional[int], typer.Option("--count", "-n", help="Stop after this many messages.", show_default=False)] = None,
    distro: Annotated[Optional[str], typer.Option(help="The distro whose message definitions the topic's type is read with \\[default: ROS_DISTRO, else humble].", show_default=False)] = None,
    qos: Annotated[str, typer.Option(help="The subscription's reliability: reliable, best-effort, or auto (as the topic's first publisher offers it).")] = "auto",
) -> None:
    """Subscribe to TOPIC over DDS as a ROS 2 node would (no ROS install; the extra ros2; ROS_DOMAIN_ID, ROS_LOCALHOST_ONLY, ROS_AUTOMATIC_DISCOVERY_RANGE and CYCLONEDDS_URI as ROS 2 reads them) and print its messages as the CSV `rostopic echo -p` prints on ROS 1: a %time header, then one row per message, flushed. `mlnseq echo /joint_states | mlnseq stream MODEL` recognises them live. SIGINT or SIGTERM stops it (exit 0)."""
    options = stage.EchoOptions(topic=topic, count=count, distro=distro, qos=qos)

    def emit(line: str) -> None:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()

    def warn(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    with reported_errors():
        try:
            summary = stage.run(options, emit, warn)
        except BrokenPipeError:  # the reader went away (`| head`, stream stopped): nothing more to say
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return
    skipped = f", {counted(summary.skipped, 'message')} skipped (other fields)" if summary.skipped else ""
    warn(f"echo: {counted(summary.messages, 'message')} of {topic}{skipped}")
