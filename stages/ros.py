"""ros: a ROS node recognising live topics with a model file trained on ROS bags: ROS 2 over DDS
(stages/dds/node.py: a Cyclone DDS participant, no ROS install) or ROS 1 (rospy, below).

It subscribes to the topics the model was trained on (its manifest's ``reading``), puts their messages on the
model's clock as collect put the bags on it, runs the same `Recognizer` as predict and stream on every tick
(stages/recognition/live.py, which the ROS 2 node runs as well), and publishes per tick the
class name (std_msgs/String on ``activity_topic``) and the frame as stream writes it, with its time and every
class's probability (a JSON std_msgs/String on ``activity_topic``/frame). A message the model cannot use is
one line on stderr and the node goes on; only start-up errors stop it (BadInput, exit 2).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from mlnseq.catalog.errors import BadInput, check_choice
from mlnseq.catalog.methods import member
from mlnseq.dds.domain import QosChoice
from mlnseq.recognition.live import LiveFrame, MessageFeed
from mlnseq.recognition.recognizer import Recognizer

ACTIVITY_TOPIC = "/mlnseq/activity"
FRAME_SUFFIX = "/frame"  # the JSON frame's topic, below the activity's
QUEUE = 1000  # messages a subscriber or publisher holds before dropping the oldest: 10 s at 100 Hz
ROS_PACKAGES = "python3-rospy python3-rosmaster python3-rostopic python3-std-msgs python3-sensor-msgs"


class RosVersion(StrEnum):
    """``--ros``: which ROS the node speaks."""

    AUTO = "auto"  # ROS_VERSION where a ROS set-up was sourced, else ROS 1 where ROS_MASTER_URI is set, else ROS 2
    ONE = "1"
    TWO = "2"


@dataclass(frozen=True)
class RosOptions:
    """Options of `mlnseq ros`."""

    model: Path
    activity_topic: str = ACTIVITY_TOPIC
    node_name: str = "mlnseq"
    ros: RosVersion | str = RosVersion.AUTO
    distro: str | None = None  # ROS 2's message definitions: default ROS_DISTRO where it is a ROS 2 one, else humble
    qos: QosChoice | str = QosChoice.AUTO  # ROS 2: the subscriptions' reliability

    def __post_init__(self) -> None:
        object.__setattr__(self, "ros", member(RosVersion, self.ros))
        object.__setattr__(self, "qos", member(QosChoice, self.qos))

    def validate(self) -> None:
        if not self.activity_topic.strip() or " " in self.activity_topic:
            raise BadInput(f"--topic {self.activity_topic!r}: not a ROS topic name")
        check_choice("ros", self.ros, tuple(RosVersion))
        check_choice("qos", self.qos, tuple(QosChoice))

    def version(self) -> RosVersion:
        """The ROS spoken: --ros, else the environment's."""
        if self.ros is not RosVersion.AUTO:
            return self.ros
        sourced = os.environ.get("ROS_VERSION", "").strip()
        if sourced in ("1", "2"):
            return RosVersion(sourced)
        return RosVersion.ONE if os.environ.get("ROS_MASTER_URI", "").strip() else RosVersion.TWO


@dataclass
class RosSummary:
    frames: int = 0
    errors: int = 0


def rospy_modules() -> tuple[Any, Any, Any]:
    """rospy, roslib.message and std_msgs' String; one line saying how to install them if absent."""
    try:
        import rospy
        from roslib import message as roslib_message
        from std_msgs.msg import String
    except ImportError as error:
        raise BadInput(f"mlnseq ros needs ROS 1's rospy ({error.name or error} is missing): source your ROS "
                       "setup.bash, "
                       f"or on Debian `apt-get install {ROS_PACKAGES}` (scripts/setup.sh does it)") from None
    return rospy, roslib_message, String


def check_master() -> str:
    """The master's URI; refuses when none answers there."""
    import rosgraph

    uri = rosgraph.get_master_uri()
    try:
        rosgraph.Master("/mlnseq").getPid()
    except Exception:  # socket errors, refused connections: no master there
        raise BadInput(f"no ROS master answers at {uri} (ROS_MASTER_URI): start roscore, "
                       "or set ROS_MASTER_URI") from None
    return uri


def run(options: RosOptions, warn: Callable[[str], None], stop: threading.Event | None = None) -> RosSummary:
    """Run the node until SIGINT or SIGTERM (or ``stop``); the frames it answered and the errors it said."""
    options.validate()
    if options.version() is RosVersion.TWO:
        return run_dds(options, warn, stop)
    rospy, roslib_message, String = rospy_modules()
    model = Recognizer.load(options.model)
    feed = MessageFeed(model, warn, time.monotonic)
    uri = check_master()
    stop = stop or threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    rospy.init_node(options.node_name, disable_signals=True)
    activity = rospy.Publisher(options.activity_topic, String, queue_size=QUEUE)
    framed = rospy.Publisher(options.activity_topic.rstrip("/") + FRAME_SUFFIX, String, queue_size=QUEUE)
    lock, classes = threading.Lock(), {}

    def publish(frames: list[LiveFrame]) -> None:
        for frame in frames:
            activity.publish(String(data=frame.prediction.name))
            framed.publish(String(data=frame.json(model.classes)))

    def receive(raw: Any, topic: str) -> None:
        received = rospy.get_rostime().to_nsec()
        kind = raw._connection_header.get("type", "?")
        if kind not in classes:
            classes[kind] = roslib_message.get_message_class(kind)
            if classes[kind] is None:
                feed.error(topic, f"{topic} sends {kind}, a message type this node cannot import: install its package")
        if classes[kind] is None:
            return
        with lock:
            publish(feed.receive(topic, classes[kind]().deserialize(raw._buff), received))

    for topic in feed.topics:
        rospy.Subscriber(topic, rospy.AnyMsg, receive, callback_args=topic, queue_size=QUEUE)
    warn(f"ros: {options.node_name} at {uri}: listening to {', '.join(feed.topics)} on the model's "
         f"{feed.live.rate:g} Hz clock; publishing {options.activity_topic} and "
         f"{options.activity_topic.rstrip('/')}{FRAME_SUFFIX}")
    while not stop.wait(0.1) and not rospy.is_shutdown():
        pass
    with lock:
        publish(feed.finish())
    rospy.signal_shutdown("mlnseq ros stopped")
    return RosSummary(feed.frames, feed.bad)


def run_dds(options: RosOptions, warn: Callable[[str], None], stop: threading.Event | None = None) -> RosSummary:
    """The ROS 2 node (stages/dds/node.py) until SIGINT or SIGTERM (or ``stop``)."""
    from mlnseq.dds import node, require, stopped_by_signals, types

    require()
    node_options = node.NodeOptions(options.model, options.activity_topic, options.node_name,
                                    options.distro or types.default_distro(), options.qos)
    with stopped_by_signals(stop) as stop:
        return RosSummary(*node.run(node_options, warn, stop))
