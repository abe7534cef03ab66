"""ros: a ROS 1 node (rospy) recognising live topics with a model file trained on ROS bags.

It subscribes to the topics the model was trained on (its manifest's ``reading``), puts their messages on the
model's clock as collect put the bags on it, runs the same `Recognizer` as predict and stream on every tick
(stages/recognition/live.py, which a ROS 2 node can use as well: docs/ros.md), and publishes per tick the
class name (std_msgs/String on ``activity_topic``) and the frame as stream writes it, with its time and every
class's probability (a JSON std_msgs/String on ``activity_topic``/frame). A message the model cannot use is
one line on stderr and the node goes on; only start-up errors stop it (BadInput, exit 2).
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mlnseq.catalog.errors import BadInput
from mlnseq.recognition.live import LiveFrame, MessageFeed
from mlnseq.recognition.recognizer import Recognizer

ACTIVITY_TOPIC = "/mlnseq/activity"
FRAME_SUFFIX = "/frame"  # the JSON frame's topic, below the activity's
QUEUE = 1000  # messages a subscriber or publisher holds before dropping the oldest: 10 s at 100 Hz
ROS_PACKAGES = "python3-rospy python3-rosmaster python3-rostopic python3-std-msgs python3-sensor-msgs"


@dataclass(frozen=True)
class RosOptions:
    """Options of `mlnseq ros`."""

    model: Path
    activity_topic: str = ACTIVITY_TOPIC
    node_name: str = "mlnseq"

    def validate(self) -> None:
        if not self.activity_topic.strip() or " " in self.activity_topic:
            raise BadInput(f"--topic {self.activity_topic!r}: not a ROS topic name")


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
