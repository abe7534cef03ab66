"""Live ROS messages as frames: `rostopic echo -p` CSV rows and ROS message objects (rospy, rclpy) read into
the feature names collect gives a bag's topics, and the hold-last clock collect puts a bag on, one message at
a time.

Feature names are those of stages/sources/rosbag.py: ``TOPIC/FIELD/PATH``, array elements by index, a
``sensor_msgs/JointState``'s by joint name. A message's time is its header stamp, else its receive time.
`HoldLast` ticks at the model's rate from the message that completes every topic, each tick holding each
topic's last value at or before it: a tick is known once a later message arrives (or the feed ends), so a
1 kHz feed gives the frames a 100 Hz one does.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mlnseq.catalog.errors import BadInput

HEADER_START = "%time"  # the first column of `rostopic echo -p`
FIELD = "field."
STAMP, NAMES = "field.header.stamp", "field.name"
JOINT_ARRAYS = ("position", "velocity", "effort")  # a JointState's arrays, labelled by joint name


def is_header(line: str) -> bool:
    """Whether ``line`` is the header `rostopic echo -p` prints first."""
    return line.lstrip().startswith(HEADER_START + ",") or line.strip() == HEADER_START


def topic_of(feature: str, topics: Sequence[str]) -> str | None:
    """The topic a feature belongs to: the longest of ``topics`` it starts with."""
    owners = [t for t in topics if feature.startswith(t.rstrip("/") + "/")]
    return max(owners, key=len) if owners else None


def features_by_topic(features: Sequence[str], topics: Sequence[str]) -> dict[str, list[int]]:
    """Each topic's features, as positions in ``features``; refuses a feature no topic owns."""
    owned: dict[str, list[int]] = {t: [] for t in topics}
    for i, name in enumerate(features):
        topic = topic_of(name, topics)
        if topic is None:
            raise BadInput(f"the model's feature {name!r} belongs to none of its topics ({', '.join(topics)})")
        owned[topic].append(i)
    return owned


# --- `rostopic echo -p` CSV -------------------------------------------------------------------------


def _column(path: list[str]) -> str:
    """The CSV column of a field path: ``poses/0/position/x`` -> ``field.poses0.position.x``."""
    text = "field"
    for step in path:
        text += step if step.isdigit() else "." + step
    return text


@dataclass(frozen=True)
class CsvMessage:
    """One `rostopic echo -p` row: its time in ns and the values of the features it carries."""

    time: int
    values: dict[str, float]


class EchoCsv:
    """Reads `rostopic echo -p TOPIC` rows as ``topic``'s features (``wanted``: the model's feature names)."""

    def __init__(self, header: str, topic: str, wanted: Sequence[str]):
        self.columns = next(csv.reader([header]))
        self.index = {name: i for i, name in enumerate(self.columns)}
        self.topic = topic.rstrip("/")
        self.names = [i for i, c in enumerate(self.columns) if c.startswith(NAMES) and c[len(NAMES):].isdigit()]
        self.plain: dict[str, int] = {}  # feature -> column, for fields found by their path
        self.joints: dict[str, tuple[str, str]] = {}  # feature -> (array, joint name), looked up per row
        for feature in wanted:
            path = feature[len(self.topic) + 1:].split("/")
            if len(path) == 2 and path[0] in JOINT_ARRAYS and not path[1].isdigit():
                if not self.names:
                    raise BadInput(f"the feed has no joint names (field.name0 ...) for the model's feature "
                                   f"{feature!r}: is it `rostopic echo -p {self.topic}`, a sensor_msgs/JointState "
                                   "topic?")
                self.joints[feature] = (path[0], path[1])
            elif _column(path) in self.index:
                self.plain[feature] = self.index[_column(path)]
            else:
                fields = ", ".join(c for c in self.columns[1:8]) + (" ..." if len(self.columns) > 8 else "")
                raise BadInput(f"the feed has no field {_column(path)} for the model's feature {feature!r} (its "
                               f"fields: {fields}); is it `rostopic echo -p {self.topic}`?")

    def row(self, line: str) -> CsvMessage:
        """One row's time and feature values; BadInput for a row that cannot be read."""
        row = next(csv.reader([line]))
        if len(row) != len(self.columns):
            raise BadInput(f"{len(row)} fields, the header has {len(self.columns)}")
        stamp = row[self.index[STAMP]] if STAMP in self.index else ""
        time = _integer(stamp) or _integer(row[0])
        if not time:
            raise BadInput("no time: the header stamp and %time are 0 or empty; stamp the messages")
        values = {feature: _float(row[i], feature) for feature, i in self.plain.items()}
        if self.joints:
            joint_index = {row[i]: i - self.names[0] for i in self.names}
            for feature, (array, joint) in self.joints.items():
                column = self.index.get(f"{FIELD}{array}{joint_index.get(joint, -1)}")
                if joint not in joint_index or column is None:
                    raise BadInput(f"no {array} of joint {joint!r} (feature {feature!r}); the message names "
                                   f"{', '.join(row[i] for i in self.names)}")
                values[feature] = _float(row[column], feature)
        return CsvMessage(time, values)


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        return 0


def _float(text: str, feature: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise BadInput(f"feature {feature!r} is {text!r}, not a number") from None


# --- message objects (rospy, rclpy) -----------------------------------------------------------------


def message_fields(message: Any) -> list[str]:
    """A message object's field names: rclpy's ``get_fields_and_field_types``, else rospy's ``__slots__``."""
    if hasattr(message, "get_fields_and_field_types"):
        return list(message.get_fields_and_field_types())
    return list(getattr(message, "__slots__", ()))


def message_time(message: Any) -> int:
    """A message's header stamp in ns, 0 without one (rospy's ``to_nsec``, rclpy's ``sec``/``nanosec``)."""
    stamp = getattr(getattr(message, "header", None), "stamp", None)
    if stamp is None:
        return 0
    if hasattr(stamp, "to_nsec"):
        return int(stamp.to_nsec())
    return int(stamp.sec) * 10**9 + int(getattr(stamp, "nanosec", getattr(stamp, "nsecs", 0)))


def message_values(message: Any, topic: str) -> dict[str, float]:
    """Every numeric field of a message object under collect's feature names (a JointState's arrays by joint
    name; the top header, text and byte arrays left out)."""
    found: dict[str, float] = {}
    fields = message_fields(message)
    joints = list(message.name) if {"name", *JOINT_ARRAYS} <= set(fields) else None

    def walk(value: Any, name: str, top: bool) -> None:
        if isinstance(value, (bool, int, float, np.integer, np.floating)):
            found[name] = float(value)
        elif isinstance(value, (str, bytes, bytearray)):
            return
        elif isinstance(value, (Sequence, np.ndarray)) or type(value).__name__ == "array":
            labels = joints if top and joints is not None and len(joints) == len(value) else range(len(value))
            for label, item in zip(labels, value):
                walk(item, f"{name}/{label}", False)
        elif message_fields(value):
            for field in message_fields(value):
                walk(getattr(value, field), f"{name}/{field}", False)

    for field in fields:
        if field != "header":
            walk(getattr(message, field), f"{topic.rstrip('/')}/{field}", True)
    return found


# --- the clock --------------------------------------------------------------------------------------


class OutOfOrder(BadInput):
    """A message older than its topic's previous one: dropped."""


class HoldLast:
    """collect's bag clock, online: ticks every 1/rate s from the message that completes every topic, each
    holding every topic's last values at or before it (``width`` features; ``slots[topic]``: its positions), for
    at most ``max_hold`` s: a topic silent for longer is missing (NaN) in the ticks after that, as collect drops
    those frames (stages/sources/holds.py); a topic that sent one message only (latched) is held throughout."""

    def __init__(self, slots: Mapping[str, Sequence[int]], width: int, rate: float, max_hold: float = math.inf):
        self.slots = {topic: np.asarray(positions, dtype=np.int64) for topic, positions in slots.items()}
        self.period = 1e9 / rate
        self.hold = max_hold * 1e9
        self.row = np.full(width, np.nan)
        self.seen: dict[str, int] = {}  # topic -> its last message's time
        self.sent: dict[str, int] = {}  # topic -> how many messages
        self.clock0: int | None = None
        self.tick = 0
        self.late: set[str] = set()  # topics that sent a message older than a tick already given

    def next_time(self) -> int:
        return self.clock0 + round(self.tick * self.period)

    def push(self, topic: str, time: int, values: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """The ticks this message closes (each a time in ns and a copy of the frame), then hold its values."""
        previous = self.seen.get(topic)
        if previous is not None and time < previous:
            raise OutOfOrder(f"topic {topic} goes back in time: {time} ns after {previous} ns; message dropped")
        ticks = list(self._ticks_before(time))
        if self.clock0 is not None and self.tick and time < self.clock0 + round((self.tick - 1) * self.period):
            self.late.add(topic)
        self.seen[topic] = time
        self.sent[topic] = self.sent.get(topic, 0) + 1
        self.row[self.slots[topic]] = values
        if self.clock0 is None and len(self.seen) == len(self.slots):
            self.clock0 = time
        return ticks

    def _ticks_before(self, time: int) -> Iterator[tuple[int, np.ndarray]]:
        while self.clock0 is not None and self.next_time() < time:
            tick, row = self.next_time(), self.row.copy()
            for topic in self.stale(tick):
                row[self.slots[topic]] = np.nan
            yield tick, row
            self.tick += 1

    def stale(self, tick: int) -> list[str]:
        """The topics whose last value is older than the hold at ``tick`` (ns)."""
        return [topic for topic, seen in self.seen.items() if tick - seen > self.hold and self.sent[topic] > 1]

    def finish(self) -> list[tuple[int, np.ndarray]]:
        """The ticks up to the last message, once the feed has ended."""
        if self.clock0 is None:
            return []
        return list(self._ticks_before(max(self.seen.values()) + 1))
