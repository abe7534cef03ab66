"""ros: a ROS node recognising live topics with a model file trained on ROS bags: ROS 2 over DDS
(stages/dds/node.py: a Cyclone DDS participant, no ROS install) or ROS 1 (rospy, below).

It subscribes to the topics the model was trained on (its manifest's ``reading``), puts their messages on the
model's clock as collect put the bags on it, runs the same `Recognizer` as predict and stream on every tick
(stages/recognition/live.py, which the ROS 2 node runs as well), and publishes per tick the class name
(std_msgs/String on ``activity_topic``) and the frame as stream writes it, with its time, stamp and every class's
probability, and with ``explain`` its why (a JSON std_msgs/String on ``activity_topic``/frame); ``decode`` decodes
with another decoder than the model's; with ``monitor``, an alert (a JSON std_msgs/String on ``activity_topic``/alert)
the moment a recording turns suspect, after the frames published with it. A message the model cannot use is one line
on stderr and the node goes on; a publisher of a type without the model's fields on its topic is one note naming it,
and is not read; only start-up errors stop it (BadInput, exit 2).

The callbacks only queue the messages (`MessageFeed.offer`: bounded, the oldest dropped first and counted); the
main thread recognises and publishes them. SIGINT or SIGTERM drains the queue and decides every frame held before
the node exits. A master that restarts is noticed within a second, and the node registers its publications and
subscriptions with it again (rospy does not), with a note.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from mlnseq.catalog.decoders import parse_decoding
from mlnseq.catalog.errors import BadInput, check_choice
from mlnseq.catalog.methods import member
from mlnseq.catalog.stopping import stop_on_signals
from mlnseq.dds.domain import QosChoice
from mlnseq.recognition.live import QUEUE, LiveFrame, MessageFeed, needed_fields, prepared

ACTIVITY_TOPIC = "/mlnseq/activity"
FRAME_SUFFIX = "/frame"  # the JSON frame's topic, below the activity's
ALERT_SUFFIX = "/alert"  # with --monitor: the alerts' topic, below the activity's
PUBLISHER_QUEUE = 1000  # messages a publisher holds for a slow subscriber before dropping the oldest
FLUSH_S = 0.5  # after the last frames are published, before the node's connections close
MASTER_POLL_S = 1.0  # how often the node asks whether its master is still the one it registered with
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

    max_hold: float | None = None  # seconds a tick holds a silent topic's values; default: the model's
    queue_size: int = QUEUE  # messages waiting for the recogniser; the oldest dropped beyond
    decode: str | None = None  # a decoder, as predict's --decode; default: the model's
    explain: int = 0  # N > 0: each frame's JSON carries "why", its N largest terms (docs/explain.md)
    monitor: bool = False  # TOPIC/alert gets a JSON line the moment a recording turns suspect (docs/audit.md)

    def __post_init__(self) -> None:
        object.__setattr__(self, "ros", member(RosVersion, self.ros))
        object.__setattr__(self, "qos", member(QosChoice, self.qos))

    def validate(self) -> None:
        if not self.activity_topic.strip() or " " in self.activity_topic:
            raise BadInput(f"--topic {self.activity_topic!r}: not a ROS topic name")
        check_choice("ros", self.ros, tuple(RosVersion))
        check_choice("qos", self.qos, tuple(QosChoice))
        if self.max_hold is not None and not self.max_hold > 0:
            raise BadInput(f"--max-hold must be above 0 seconds (inf: no bound), got {self.max_hold:g}")
        if self.queue_size < 1:
            raise BadInput(f"--queue-size must be at least 1 message, got {self.queue_size}")
        if self.explain < 0:
            raise BadInput(f"--explain {self.explain}: give how many terms each frame shows (0: none)")
        if self.decode is not None:
            parse_decoding(self.decode)

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
    dropped: int = 0


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


def numeric_slots(kind: Any, message_class: Callable[[str], Any]) -> set[str]:
    """A rospy message class's top-level fields that hold numbers (a number, an array of numbers, or a message
    holding some; the header aside), as the DDS node reads its types (stages/dds/types.py)."""
    def numeric(slot_type: str) -> bool:
        base = slot_type.split("[", 1)[0]
        if "/" not in base:  # a number, bool, time or duration; or text
            return base != "string"
        inner = message_class(base)
        return inner is not None and any(numeric(t) for t in inner._slot_types)

    slots = zip(kind.__slots__, kind._slot_types)
    return {name for name, slot_type in slots if name != "header" and numeric(slot_type)}


class RawMessages:
    """rospy.AnyMsg's messages read as their publishers' types (a subscription hears every publisher of its topic):
    a type this node cannot import is an error line; a type holding none of the fields the model's features come from
    (a std_msgs/String on /joint_states) is one note naming its publisher, whose messages are then not read."""

    def __init__(self, model: Any, message_class: Callable[[str], Any], warn: Callable[[str], None]):
        self.message_class, self.warn = message_class, warn
        self.needs = needed_fields(model)
        self.error: Callable[[str, str], None] = lambda topic, text: warn(f"error: {text}")  # the feed's, once made
        self.classes: dict[str, Any] = {}
        self.missing: dict[tuple[str, str], set[str]] = {}  # (topic, type) -> the model's fields the type lacks
        self.strays: set[tuple[str, str, str]] = set()  # (topic, publisher, type) said

    def __call__(self, topic: str, raw: Any) -> Any:
        kind = raw._connection_header.get("type", "?")
        if kind not in self.classes:
            self.classes[kind] = self.message_class(kind)
            if self.classes[kind] is None:
                self.error(topic, f"{topic} sends {kind}, a message type this node cannot import: install its package")
        if self.classes[kind] is None:
            return None
        if (topic, kind) not in self.missing:
            self.missing[topic, kind] = self.needs[topic] - numeric_slots(self.classes[kind], self.message_class)
        missing = self.missing[topic, kind]
        if missing:
            caller = raw._connection_header.get("callerid", "?")
            if (topic, caller, kind) not in self.strays:
                self.strays.add((topic, caller, kind))
                self.warn(f"note: a publisher on {topic} sends {kind}, which holds no {', '.join(sorted(missing))} "
                          f"for the model's features: {caller} is not read; {topic} is read from the publishers of "
                          "the type that holds them")
            return None
        return self.classes[kind]().deserialize(raw._buff)


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


def register_again(rospy: Any) -> tuple[int, int]:
    """Register this node's publications and subscriptions with the master again, each subscription told the
    master's publishers (as rospy does at start-up); how many of each."""
    import xmlrpc.client

    import rosgraph
    from rospy.impl.registration import get_topic_manager

    master, node = rosgraph.Master(rospy.get_name()), rospy.get_node_uri()
    manager = get_topic_manager()
    publications, subscriptions = manager.get_publications(), manager.get_subscriptions()
    for topic, kind in publications:
        master.registerPublisher(topic, kind, node)
    for topic, kind in subscriptions:
        publishers = master.registerSubscriber(topic, kind, node)
        xmlrpc.client.ServerProxy(node).publisherUpdate("/master", topic, publishers)
    return len(publications), len(subscriptions)


def watch_master(rospy: Any, uri: str, warn: Callable[[str], None], stop: threading.Event) -> None:
    """Until ``stop``: ask the master its process id every MASTER_POLL_S; when it went away and came back (or
    another answers), register again and say so."""
    import rosgraph

    master = rosgraph.Master(rospy.get_name())
    known: int | None = master.getPid()
    while not stop.wait(MASTER_POLL_S):
        try:
            pid = master.getPid()
        except Exception:  # refused, reset: the master is gone for now
            if known is not None:
                warn(f"ros: the master at {uri} is gone; the node goes on with the connections it has, and "
                     "registers again when a master answers")
            known = None
            continue
        if pid != known:
            try:
                publications, subscriptions = register_again(rospy)
            except Exception as error:  # it went away again: the next poll retries
                warn(f"ros: the master at {uri} answers but refused the registration ({error}); retrying")
                continue
            warn(f"ros: the master at {uri} is back (process {pid}): registered again {publications} publications "
                 f"and {subscriptions} subscriptions")
            known = pid


def run(options: RosOptions, warn: Callable[[str], None], stop: threading.Event | None = None) -> RosSummary:
    """Run the node until SIGINT or SIGTERM (or ``stop``); the frames it answered and the errors it said."""
    options.validate()
    if options.version() is RosVersion.TWO:
        return run_dds(options, warn, stop)
    rospy, roslib_message, String = rospy_modules()
    model = prepared(options.model, warn, options.decode, options.explain)
    if options.monitor:
        from mlnseq.auditing import monitor

        model = monitor.monitored(model, options.model)
    decode = RawMessages(model, roslib_message.get_message_class, warn)
    feed = MessageFeed(model, warn, time.monotonic, options.max_hold, options.queue_size, decode)
    decode.error = feed.error
    uri = check_master()
    with stop_on_signals(stop) as heard:
        stop = heard.stop
        rospy.init_node(options.node_name, disable_signals=True)
        activity = rospy.Publisher(options.activity_topic, String, queue_size=PUBLISHER_QUEUE)
        framed = rospy.Publisher(options.activity_topic.rstrip("/") + FRAME_SUFFIX, String,
                                 queue_size=PUBLISHER_QUEUE)
        alerting = rospy.Publisher(options.activity_topic.rstrip("/") + ALERT_SUFFIX, String,
                                   queue_size=PUBLISHER_QUEUE) if options.monitor else None

        def publish(frames: list[LiveFrame]) -> None:
            for frame in frames:
                activity.publish(String(data=frame.prediction.name))
                framed.publish(String(data=frame.json(model.classes)))
            for line in monitor.alert_lines(model, frames) if alerting is not None else ():
                alerting.publish(String(data=line))

        for topic in feed.topics:
            rospy.Subscriber(topic, rospy.AnyMsg, lambda raw, t: feed.offer(t, raw, rospy.get_rostime().to_nsec()),
                             callback_args=topic, queue_size=options.queue_size)
        threading.Thread(target=watch_master, args=(rospy, uri, warn, stop), daemon=True).start()
        warn(f"ros: {options.node_name} at {uri}: listening to {', '.join(feed.topics)} on the model's "
             f"{feed.live.rate:g} Hz clock; publishing {options.activity_topic} and "
             f"{options.activity_topic.rstrip('/')}{FRAME_SUFFIX}")
        while not stop.is_set() and not rospy.is_shutdown():
            publish(feed.pending(0.1))
        last = feed.drain()  # what was queued, and every frame held (a lagged decoder's last frames), decided
        publish(last)
        if last:
            time.sleep(FLUSH_S)  # rospy sends from a thread per connection: let the last frames leave
        rospy.signal_shutdown("mlnseq ros stopped")
    return RosSummary(feed.frames, feed.bad, feed.dropped)


def run_dds(options: RosOptions, warn: Callable[[str], None], stop: threading.Event | None = None) -> RosSummary:
    """The ROS 2 node (stages/dds/node.py) until SIGINT or SIGTERM (or ``stop``)."""
    from mlnseq.dds import node, require, types

    require()
    node_options = node.NodeOptions(options.model, options.activity_topic, options.node_name,
                                    options.distro or types.default_distro(), options.qos, options.max_hold,
                                    options.queue_size, options.decode, options.explain, options.monitor)
    with stop_on_signals(stop) as heard:
        return RosSummary(*node.run(node_options, warn, heard.stop))
