"""`mlnseq ros --ros 2`: the recogniser as a ROS 2 node, a DDS participant with no ROS install.

It subscribes to the model's topics as their publishers are discovered (their ROS 2 types from rosbags' typestore
for ``--distro``, only a type holding the fields the model's features come from, a stray publisher of another type
said once; the QoS they offer or ``--qos``), runs every message through the live core that the ROS 1 node
runs (recognition/live.py's `MessageFeed`: the header stamps' clock, the model's rate, several topics merged by the
model's rule, a lagged decoder's wait), and publishes per decided frame the class name (std_msgs/String on the
activity topic) and the frame as stream writes it (a JSON std_msgs/String on TOPIC/frame; with ``explain``, its
why). When ``stop`` is set
(SIGINT, SIGTERM), the samples already arrived are read, the frames the feed holds are decided and published
(`MessageFeed.drain`), and the writers wait for their readers' acknowledgements before the node leaves.

A taking thread subscribes as publishers appear and hands every sample to the feed's bounded queue
(`MessageFeed.offer`: the oldest dropped first, counted and said), so a recogniser that falls behind a fast
publisher drops what it cannot recognise in time, as the ROS 1 node does; the main thread recognises and publishes.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from mlnseq.auditing.monitor import alert_lines, monitored
from mlnseq.dds import domain, require
from mlnseq.dds.types import STRING, MessageTypes
from mlnseq.recognition.live import QUEUE, LiveFrame, MessageFeed, needed_fields, prepared

FRAME_SUFFIX = "/frame"  # the JSON frame's topic, below the activity's (as the ROS 1 node)
ALERT_SUFFIX = "/alert"  # with monitor: the alerts' topic, below the activity's (as the ROS 1 node)
WAIT_S = 0.1  # the longest the node waits for a sample before looking at discovery and the stop flag again
ACKS_S = 2.0  # at shutdown: the longest the writers wait for their readers to acknowledge the last frames


@dataclass(frozen=True)
class NodeOptions:
    """What the ROS 2 node is told: the model, the activity topic, its name, the distro's types, the QoS."""

    model: Path
    activity_topic: str
    node_name: str
    distro: str
    qos: domain.QosChoice
    max_hold: float | None = None  # seconds a tick holds a silent topic's values; default: the model's
    queue_size: int = QUEUE  # messages waiting for the recogniser; the oldest dropped beyond
    decode: str | None = None  # default: the model's
    explain: int = 0  # N > 0: each frame's JSON carries "why", its N largest terms
    monitor: bool = False  # alerts on TOPIC/alert the moment a recording turns suspect (stages/auditing/monitor.py)

    @property
    def frame_topic(self) -> str:
        return self.activity_topic.rstrip("/") + FRAME_SUFFIX

    @property
    def alert_topic(self) -> str:
        return self.activity_topic.rstrip("/") + ALERT_SUFFIX


def run(options: NodeOptions, warn: Callable[[str], None], stop: threading.Event) -> tuple[int, int, int]:
    """Run the node until ``stop`` is set; the frames it answered, the bad messages it said and the messages it
    dropped."""
    require()
    model = prepared(options.model, warn, options.decode, options.explain)
    if options.monitor:
        model = monitored(model, options.model)
    feed = MessageFeed(model, warn, time.monotonic, options.max_hold, options.queue_size)
    types = MessageTypes(options.distro)
    String = types.get(STRING)
    participant = domain.Participant(options.distro, options.node_name)
    activity = participant.writer(options.activity_topic, String)
    framed = participant.writer(options.frame_topic, String)
    alerting = participant.writer(options.alert_topic, String) if options.monitor else None
    subscriptions = domain.Subscriptions(participant, types, feed.topics, options.qos, feed.error,
                                         needed_fields(model), warn)

    def publish(frames: list[LiveFrame]) -> None:
        for frame in frames:
            activity.write(String(data=frame.prediction.name))
            framed.write(String(data=frame.json(feed.classes)))
        for line in alert_lines(model, frames) if alerting is not None else ():
            alerting.write(String(data=line))

    def take(seconds: float) -> None:
        for made in subscriptions.discover():
            warn(f"ros: subscribed to {made.describe()}")
        for topic, message, sent in subscriptions.take(seconds):
            feed.offer(topic, message, sent)

    taking = threading.Event()

    def taker() -> None:
        while not taking.is_set():
            take(WAIT_S)

    warn(f"ros: {options.node_name} on ROS 2 {options.distro} (DDS domain {participant.domain_id}): listening to "
         f"{', '.join(feed.topics)} on the model's {feed.live.rate:g} Hz clock; publishing {options.activity_topic} "
         f"and {options.frame_topic}")
    thread = threading.Thread(target=taker, name="mlnseq-dds-take", daemon=True)
    thread.start()
    while not stop.is_set():
        publish(feed.pending(WAIT_S))
    taking.set()
    thread.join()
    take(0)
    publish(feed.drain())
    participant.acknowledged((activity, framed) + ((alerting,) if alerting is not None else ()), ACKS_S)
    return feed.frames, feed.bad, feed.dropped
