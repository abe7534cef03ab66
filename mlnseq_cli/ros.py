"""`mlnseq ros`: a ROS 2 (DDS) or ROS 1 node recognising the model's topics live."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from mlnseq_cli.console import counted, reported_errors
from mlnseq import ros as stage


def ros(
    model: Annotated[Path, typer.Argument(help="A model file written by `mlnseq export`, trained on ROS bags.", dir_okay=False)],
    topic: Annotated[str, typer.Option(help="Where the activity goes (std_msgs/String, the class name); TOPIC/frame gets the frame as JSON (time, stamp, class, probabilities).")] = stage.ACTIVITY_TOPIC,
    name: Annotated[str, typer.Option(help="The node's name.")] = "mlnseq",
    ros: Annotated[str, typer.Option("--ros", help="1 or 2; auto: ROS_VERSION where a ROS set-up was sourced, else 1 where ROS_MASTER_URI is set, else 2.")] = "auto",
    distro: Annotated[Optional[str], typer.Option(help="ROS 2: the distro whose message definitions the topics' types are read with \\[default: ROS_DISTRO, else humble].", show_default=False)] = None,
    qos: Annotated[str, typer.Option(help="ROS 2: the subscriptions' reliability: reliable, best-effort, or auto (as the topic's first publisher offers it).")] = "auto",
    max_hold: Annotated[Optional[float], typer.Option(help="The longest a frame holds a silent topic's last message, in seconds (inf: no bound); past it the frames are skipped, with a note \\[default: the model's].")] = None,
    queue_size: Annotated[int, typer.Option(help="Messages waiting for the recogniser; when it falls behind, the oldest are dropped first, counted and said.")] = stage.QUEUE,
    decode: Annotated[Optional[str], typer.Option(help="A decoder, with @LAG for smooth and lagviterbi (e.g. smooth-legal@5), \\[default: the model's]; viterbi or posterior need a whole recording: live, the filter decodes with the same factors, and a note says so.")] = None,
    explain: Annotated[int, typer.Option(help="Add \"why\" to each frame's JSON: the N largest terms of its margin (kind, text, line, contribution; docs/explain.md), as explain gives them; off by default.")] = 0,
    monitor: Annotated[bool, typer.Option("--monitor", help="Audit each recording as it goes (docs/audit.md): the moment one turns suspect, a JSON std_msgs/String with an \"alert\" key on TOPIC/alert, after the frames published with it.")] = False,
) -> None:
    """Subscribe to the topics MODEL was trained on (it remembers them, and their rate), recognise every tick of its clock as predict and stream do, and publish the class name on --topic and the frame as JSON ({"episode", "frame", "time", "stamp", "class", "probabilities", "lag"} and, with --explain, "why", as stream writes it; time: seconds from the episode's first message, stamp: the messages' clock) on TOPIC/frame. A topic published under several types is read as the type that holds the model's fields; each stray publisher is one note. ROS 2: a DDS participant (Cyclone DDS; no ROS install; the extra ros2) on ROS_DOMAIN_ID, with ROS_LOCALHOST_ONLY, ROS_AUTOMATIC_DISCOVERY_RANGE and CYCLONEDDS_URI as a ROS 2 node reads them. ROS 1: rospy and a running master (ROS_MASTER_URI); a master that restarts is registered with again. A message the model cannot use is one line on stderr and the node goes on. SIGINT or SIGTERM stops it, once every message received is recognised and every frame held is decided and published."""
    options = stage.RosOptions(model=model, activity_topic=topic, node_name=name, ros=ros, distro=distro, qos=qos,
                               max_hold=max_hold, queue_size=queue_size, decode=decode, explain=explain,
                               monitor=monitor)

    def warn(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    with reported_errors():
        summary = stage.run(options, warn)
    dropped = f", {counted(summary.dropped, 'message')} dropped" if summary.dropped else ""
    warn(f"ros: stopped after {counted(summary.frames, 'frame')} ({counted(summary.errors, 'bad message')}{dropped})")
