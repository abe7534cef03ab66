"""The ROS 2 tests' DDS peers, each run as its own process: plain Cyclone DDS participants that speak as ROS 2 nodes
do, written here by hand and apart from mlnseq's own DDS code (stages/dds/), so that the names, types and bytes
the node uses are checked against an independent peer: topics ``rt/...``, types ``pkg::msg::dds_::Type_`` as
``@final`` structs, ROS's default QoS (reliable, volatile, keep last 10), and for the gripper's std_msgs/Float64
ROS's sensor-data QoS (best effort, keep last 5).

    python tests/dds_driver.py publish BAG SUBSCRIBERS [SPEED]  # a ROS 2 bag's messages (their CDR bytes as read)
                                  # at their recorded times and pace (SPEED times faster), once each topic has
                                  # SUBSCRIBERS readers
    python tests/dds_driver.py record TOPIC FILE        # each std_msgs/String's data a line; "ready" on stdout
    python tests/dds_driver.py wrong TOPIC [SECONDS [NAME]]  # a std_msgs/String publisher on TOPIC for a second (or
                                  # SECONDS), its participant named NAME

The domain and discovery come from the environment (ROS_DOMAIN_ID, CYCLONEDDS_URI), as the tests set them.
"""

# no `from __future__ import annotations`: cyclonedds reads the fields' types from the live annotations

import os
import sys
import time
from dataclasses import dataclass, field

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

WAIT_S = 30


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32
    nanosec: t.uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header
    name: t.sequence[str] = field(default_factory=list)
    position: t.sequence[t.float64] = field(default_factory=list)
    velocity: t.sequence[t.float64] = field(default_factory=list)
    effort: t.sequence[t.float64] = field(default_factory=list)


@dataclass
class Float64(IdlStruct, typename="std_msgs::msg::dds_::Float64_"):
    data: t.float64


@dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str


TYPES = {"sensor_msgs/msg/JointState": JointState, "std_msgs/msg/Float64": Float64, "std_msgs/msg/String": String}
DEFAULT = Qos(Policy.Reliability.Reliable(max_blocking_time=10**8), Policy.Durability.Volatile,
              Policy.History.KeepLast(10))  # rclcpp's default publisher / subscription QoS
SENSOR = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(5))  # SensorDataQoS
QOS = {"std_msgs/msg/Float64": SENSOR}  # the gripper's state, published as sensor data; the rest ROS's default


def participant(name: str = "") -> DomainParticipant:
    return DomainParticipant(int(os.environ["ROS_DOMAIN_ID"]), qos=Qos(Policy.EntityName(name)) if name else None)


def wait_until(check, what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not check():
        if time.monotonic() > deadline:
            sys.exit(f"dds_driver: no {what} after {WAIT_S} s")
        time.sleep(0.02)


def publish(bag: str, subscribers: int, speed: float = 1.0) -> None:
    """The bag's messages (but /phase), each its CDR bytes read as the type above, at the pace they were recorded
    (``speed`` times faster)."""
    from pathlib import Path

    from rosbags.highlevel import AnyReader

    dp = participant()
    with AnyReader([Path(bag)]) as reader:
        connections = [c for c in reader.connections if c.topic != "/phase"]
        writers = {c.topic: DataWriter(dp, Topic(dp, "rt" + c.topic, TYPES[c.msgtype]), qos=QOS.get(c.msgtype, DEFAULT))
                   for c in connections}
        wait_until(lambda: all(len(w.get_matched_subscriptions()) >= subscribers for w in writers.values()),
                   f"{subscribers} readers of {', '.join(writers)}")
        time.sleep(0.5)  # a writer sees its reader before the reader sees it: a first sample now could be missed
        begin, first = time.monotonic(), None
        for connection, timestamp, raw in reader.messages(connections=connections):
            first = timestamp if first is None else first
            time.sleep(max(0.0, begin + (timestamp - first) / 1e9 / speed - time.monotonic()))
            # the record time as the sample's source timestamp: a headerless message's time, as when it was recorded
            writers[connection.topic].write(TYPES[connection.msgtype].deserialize(bytes(raw)), timestamp=timestamp)
        for writer in writers.values():
            writer.wait_for_acks(10**10)
    time.sleep(0.5)  # let discovery see the last samples' writers still alive


def record(topic: str, path: str) -> None:
    """Each std_msgs/String's data on ``topic``, a line of ``path``; "ready" once a publisher matches."""
    dp = participant()
    qos = Qos(Policy.Reliability.Reliable(max_blocking_time=10**8), Policy.Durability.Volatile,
              Policy.History.KeepLast(10**4))
    reader = DataReader(dp, Topic(dp, "rt" + topic, String), qos=qos)
    with open(path, "a") as out:
        deadline = time.monotonic() + WAIT_S
        while not reader.get_matched_publications() and time.monotonic() < deadline:
            time.sleep(0.02)
        print("ready" if reader.get_matched_publications() else "no publisher", flush=True)
        while True:
            for sample in reader.take_iter(timeout=10**8):
                out.write(sample.data + "\n")
                out.flush()


def wrong(topic: str, seconds: str = "1", name: str = "") -> None:
    """Another type on ``topic``: a std_msgs/String publisher, for a second (or ``seconds``)."""
    dp = participant(name)
    writer = DataWriter(dp, Topic(dp, "rt" + topic, String), qos=DEFAULT)
    for _ in range(round(float(seconds) * 10)):
        writer.write(String(data="hello"))
        time.sleep(0.1)


if __name__ == "__main__":
    command, *args = sys.argv[1:]
    {"publish": lambda bag, n, speed="1": publish(bag, int(n), float(speed)), "record": record,
     "wrong": wrong}[command](*args)
