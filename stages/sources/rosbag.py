"""ROS bags as recordings, read with ``rosbags`` (no ROS install): a ROS 1 ``.bag``, a ROS 2 bag folder
(``metadata.yaml``; sqlite3 or MCAP storage), a bare ``.mcap``, or a folder of them, one episode each.

Numeric fields are flattened into features named ``TOPIC/FIELD/PATH`` (array elements by index, a
``sensor_msgs/JointState``'s by joint name; headers, text and byte arrays are left out). All topics are put
on one clock at ``rate`` Hz (default: the first topic's rate), starting when every topic has sent a message,
each tick holding each topic's last value at or before it (causal: never a value from the future). A frame's
time is seconds since the bag's first message, the bag's own record time. ``label_topic`` (std_msgs/String)
labels every tick with its last message. Messages are streamed, never all held.
"""

from __future__ import annotations

import dataclasses
import operator
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog.errors import BadInput
from mlnseq.sources.table import check_features
from mlnseq.sources.recording import Labels, Recording, TableColumns

BAG_SUFFIXES = (".bag", ".mcap")
STRING = "std_msgs/msg/String"
JOINT_STATE = "sensor_msgs/msg/JointState"
RATE_PROBE = 200  # messages of the first topic whose median period gives the default rate
CHUNK = 8192  # frames per buffer block


def bag_paths(source: Path) -> list[Path]:
    """The bags at ``source``: itself, or a folder's bags (files and ROS 2 bag folders) in name order."""
    if source.is_file():
        if source.suffix.lower() not in BAG_SUFFIXES:
            raise BadInput(f"--source {source}: expected a .bag or .mcap file, a ROS 2 bag folder, or a folder of them")
        return [source]
    if (source / "metadata.yaml").is_file():
        return [source]
    found = sorted(p for p in source.iterdir()
                   if (p.is_file() and p.suffix.lower() in BAG_SUFFIXES) or (p / "metadata.yaml").is_file())
    if not found:
        raise BadInput(f"--source {source} holds no .bag, .mcap or ROS 2 bag folder (metadata.yaml)")
    return found


def read(source: Path, columns: TableColumns, options, label: Labels = Labels.REQUIRED) -> list[Recording]:
    """One recording per bag; the topics and rate the first bag resolves hold for the others."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as error:
        from mlnseq.sources import missing_extra

        raise missing_extra("rosbags", error) from error
    typestore = get_typestore(Stores.ROS2_HUMBLE)  # for bags that carry no message definitions
    recordings: list[Recording] = []
    topics, rate = tuple(options.topics), options.rate
    for path in bag_paths(Path(source)):
        try:
            with AnyReader([path], default_typestore=typestore) as reader:
                label_topic = options.label_topic if label is not Labels.NONE else None
                if label is Labels.OPTIONAL and label_topic not in reader.topics:
                    label_topic = None  # new recordings without their phases: unlabelled
                recording = read_bag(reader, path, topics, rate, label_topic, options.unlabelled)
        except BadInput:
            raise
        except Exception as error:  # rosbags raises its own and struct/EOF errors for truncated files
            text = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            raise BadInput(f"{path}: cannot read it as a ROS bag ({text[:160]})") from error
        topics, rate = tuple(recording.resolved["topics"]), recording.resolved["rate"]
        if columns.features:
            missing = [n for n in columns.features if n not in recording.features.columns]
            if missing:
                raise BadInput(f"{path}: no feature {missing[0]!r}; its features are "
                               f"{', '.join(recording.features.columns[:8])}")
            recording = dataclasses.replace(recording, features=recording.features.select(columns.features))
        recordings.append(recording)
    return recordings


def read_bag(reader, path: Path, topics: tuple[str, ...], rate: float | None, label_topic: str | None,
             unlabelled: str | None = None) -> Recording:
    """One bag's frames; ticks before the label topic's first message are dropped, or labelled ``unlabelled``."""
    available = reader.topics
    if reader.message_count == 0:
        raise BadInput(f"{path}: the bag holds no message")
    listed = ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(available.items()))
    for topic in (*topics, *([label_topic] if label_topic else [])):
        if topic not in available:
            raise BadInput(f"{path}: no topic {topic!r}; its topics are {listed}")
        if not available[topic].msgcount:
            raise BadInput(f"{path}: topic {topic!r} has no message")
    if label_topic and available[label_topic].msgtype != STRING:
        raise BadInput(f"{path}: --label-topic {label_topic} is {available[label_topic].msgtype}, not {STRING}")
    named = bool(topics)
    candidates = list(topics) or sorted(t for t, info in available.items() if info.msgcount and t != label_topic)
    if rate is None:
        rate = _rate_of(reader, path, candidates[0])
    period = 1e9 / rate
    wanted = set(candidates) | ({label_topic} if label_topic else set())
    connections = [c for c in reader.connections if c.topic in wanted]
    joint_states = _joint_states(reader, path, [c for c in connections if c.msgtype == JOINT_STATE])

    extractors: dict[str, Callable[[Any], np.ndarray]] = {}
    names: dict[str, list[str]] = {}
    current: dict[str, np.ndarray] = {}
    last_time: dict[str, int] = {}
    skipped: list[str] = []
    start = reader.start_time
    row: np.ndarray | None = None
    offsets: dict[str, tuple[int, int]] = {}
    frames: _Blocks | None = None
    label_changes: list[tuple[int, str | None]] = [(0, None)]  # (first tick, label): ticks' times and labels follow
    tick = 0
    clock0 = None

    for connection, timestamp, raw in reader.messages(connections=connections):
        topic = connection.topic
        previous = last_time.get(topic)
        if previous is not None and timestamp < previous:
            raise BadInput(f"{path}: topic {topic!r} goes back in time at {(timestamp - start) / 1e9:.6f} s "
                           f"(after {(previous - start) / 1e9:.6f} s)")
        last_time[topic] = timestamp
        if row is not None:
            while clock0 + round(tick * period) < timestamp:  # ticks before this message hold the values so far
                frames.append(row)
                tick += 1
        message = reader.deserialize(raw, connection.msgtype)
        if topic == label_topic:
            label_changes.append((tick, message.data))
            continue
        if topic not in extractors:
            if topic in skipped:
                continue
            fields = _leaves(message, topic, connection.msgtype) if topic not in joint_states else []
            if topic in joint_states and joint_states[topic].names:  # read by joint name, not by position
                names[topic], extractors[topic] = joint_states[topic].names, joint_states[topic]
            elif not fields:
                if named:
                    raise BadInput(f"{path}: topic {topic!r} ({connection.msgtype}) has no numeric field")
                skipped.append(topic)
                candidates.remove(topic)
            else:
                names[topic] = [name for group, _, _ in fields for name in group]
                extractors[topic] = _extractor(fields)
        if topic in extractors:
            try:
                values = extractors[topic](message)
            except _JointMismatch as error:
                raise BadInput(f"{path}: topic {topic!r} at {(timestamp - start) / 1e9:.6f} s: {error}") from None
            except ValueError:
                raise BadInput(f"{path}: topic {topic!r} changes its number of values at "
                               f"{(timestamp - start) / 1e9:.6f} s; a topic's fields must keep their length") from None
            if row is not None:
                a, b = offsets[topic]
                row[a:b] = values
                continue
            if getattr(extractors[topic], "complete", True):  # a JointState topic: once every joint has a value
                current[topic] = values
        if row is None and candidates and all(t in current for t in candidates):
            position = 0
            for t in candidates:
                offsets[t] = (position, position + len(current[t]))
                position += len(current[t])
            row = np.concatenate([current[t] for t in candidates])
            frames, clock0 = _Blocks(len(row)), timestamp
    if row is None:
        if not candidates:
            raise BadInput(f"{path}: no topic has a numeric field ({listed})")
        waiting = [t for t in candidates if t not in current]
        raise BadInput(f"{path}: topic {waiting[0]!r} sent no message, so no frame has every topic's value")
    end = max(last_time.values())
    while clock0 + round(tick * period) <= end:
        frames.append(row)
        tick += 1
    feature_names = [name for t in candidates for name in names[t]]
    n = tick
    times = clock0 + np.round(np.arange(n) * period).astype(np.int64)
    labels = np.full(n, None, dtype=object)
    for (first, name), (after, _) in zip(label_changes, [*label_changes[1:], (n, None)]):
        labels[first:after] = name
    rows = np.arange(n)
    if label_topic:
        if unlabelled is not None:
            labels[labels == None] = unlabelled  # noqa: E711
        keep = labels != None  # noqa: E711
        times, labels, rows = times[keep], labels[keep], rows[keep]
        if not len(rows):
            raise BadInput(f"{path}: --label-topic {label_topic} sends its first message after the last frame")
    columns = {}
    for i, name in enumerate(feature_names):  # one column at a time: the blocks and the frames, never a third copy
        column = frames.column(i)
        columns[name] = column[keep] if label_topic else column
    del frames
    features = check_features(pl.DataFrame(columns), path, "{file} frame {row}", pl.Series(rows))
    return Recording(
        path=path, features=features, episode=pl.Series([path.stem if path.is_file() else path.name] * len(rows)),
        time=pl.Series((times - start) / 1e9),
        label=pl.Series("label", labels.tolist(), dtype=pl.String) if label_topic else None,
        row=pl.Series(rows), where="{file} frame {row}",
        resolved={"topics": list(candidates), "rate": rate, "skipped_topics": skipped},
    )


class _JointMismatch(ValueError):
    """A JointState message whose arrays do not match its joint names."""


JOINT_FIELDS = ("position", "velocity", "effort")


class _JointState:
    """A ``sensor_msgs/JointState`` topic read by joint name: every (field, joint) that any message of the
    topic carries is one feature, so several publishers (an arm and a gripper) merge by name on one clock;
    each message updates the joints it names and the others keep their last value."""

    def __init__(self, topic: str, columns: list[tuple[str, str]]):
        self.index = {column: k for k, column in enumerate(columns)}
        self.names = [f"{topic}/{field}/{joint}" for field, joint in columns]
        self.values, self.seen = np.zeros(len(columns)), np.zeros(len(columns), dtype=bool)
        self.complete = not columns

    def __call__(self, message: Any) -> np.ndarray:
        for field, joint, value in _joint_values(message):
            k = self.index[(field, joint)]
            self.values[k], self.seen[k] = value, True
        self.complete = self.complete or bool(self.seen.all())
        return self.values


def _joint_values(message: Any):
    """(field, joint, value) of every non-empty array of a JointState message, by the message's own names."""
    joints = list(message.name)
    if len(set(joints)) != len(joints):
        raise _JointMismatch(f"JointState names a joint twice ({', '.join(joints)})")
    for field in JOINT_FIELDS:
        values = np.asarray(getattr(message, field))
        if values.size and values.size != len(joints):
            raise _JointMismatch(f"JointState {field} holds {values.size} values for {len(joints)} joint names")
        if values.size:
            yield from ((field, joint, float(v)) for joint, v in zip(joints, values))


def _joint_states(reader, path: Path, connections) -> dict[str, _JointState]:
    """Each JointState topic's (field, joint) columns in order (field, then first-seen joint), from one pass
    over its messages, so that joints a second publisher sends later are not read by position."""
    columns: dict[str, dict[tuple[str, str], None]] = {c.topic: {} for c in connections}
    if not connections:
        return {}
    for connection, timestamp, raw in reader.messages(connections=connections):
        try:
            found = _joint_values(reader.deserialize(raw, connection.msgtype))
            for field, joint, _ in found:
                columns[connection.topic].setdefault((field, joint), None)
        except _JointMismatch as error:
            raise BadInput(f"{path}: topic {connection.topic!r} at {(timestamp - reader.start_time) / 1e9:.6f} s: "
                           f"{error}") from None
    return {topic: _JointState(topic, sorted(found, key=lambda c: JOINT_FIELDS.index(c[0])))
            for topic, found in columns.items()}


class _Blocks:
    """Frames held in blocks of CHUNK rows: the buffer grows without copying the frames it holds."""

    def __init__(self, width: int):
        self.full: list[np.ndarray] = []
        self.block, self.filled = np.empty((CHUNK, width)), 0

    def append(self, row: np.ndarray) -> None:
        if self.filled == CHUNK:
            self.full.append(self.block)
            self.block, self.filled = np.empty_like(self.block), 0
        self.block[self.filled] = row
        self.filled += 1

    def column(self, i: int) -> np.ndarray:
        return np.concatenate([b[:, i] for b in (*self.full, self.block[:self.filled])])


def _rate_of(reader, path: Path, topic: str) -> float:
    """The first topic's rate: 1 / the median period of its first messages (timestamps only, no decoding)."""
    stamps = []
    for connection, timestamp, _ in reader.messages(connections=[c for c in reader.connections if c.topic == topic]):
        stamps.append(timestamp)
        if len(stamps) > RATE_PROBE:
            break
    steps = np.diff(np.asarray(stamps, dtype=np.int64))
    steps = steps[steps > 0]
    if not steps.size:
        raise BadInput(f"{path}: topic {topic!r} has too few messages to give a rate; pass --rate HZ")
    return float(1e9 / np.median(steps))


def _leaves(message: Any, prefix: str, msgtype: str) -> list[tuple[list[str], Callable[[Any], Any], bool]]:
    """Every numeric field of ``message`` in field order: (its feature names, its getter, whether an array)."""
    found: list[tuple[list[str], Callable[[Any], Any], bool]] = []
    joints = list(message.name) if msgtype == JOINT_STATE else None

    def walk(value: Any, name: str, path: tuple[Any, ...]) -> None:
        if isinstance(value, (bool, int, float, np.integer, np.floating)):
            found.append(([name], _getter(path), False))
        elif isinstance(value, np.ndarray):
            if value.dtype.kind in "biuf" and value.dtype.itemsize > 1 and value.size:  # not bytes: images, blobs
                labels = joints if joints is not None and len(joints) == value.size and len(path) == 1 else range(value.size)
                found.append(([f"{name}/{label}" for label in labels], _getter(path), True))
        elif isinstance(value, list):
            for k, item in enumerate(value):
                if not isinstance(item, str):
                    walk(item, f"{name}/{k}", (*path, k))
        elif hasattr(value, "__dataclass_fields__"):
            for field in value.__dataclass_fields__:
                if field != "__msgtype__" and not (field == "header" and not path):
                    walk(getattr(value, field), f"{name}/{field}", (*path, field))

    walk(message, prefix, ())
    return found


def _getter(path: tuple[Any, ...]) -> Callable[[Any], Any]:
    if all(isinstance(step, str) for step in path):
        return operator.attrgetter(".".join(path))

    def get(message: Any) -> Any:
        for step in path:
            message = message[step] if isinstance(step, int) else getattr(message, step)
        return message
    return get


def _extractor(fields: list[tuple[list[str], Callable[[Any], Any], bool]]) -> Callable[[Any], np.ndarray]:
    """One function giving a message's values in order; an array field is copied whole."""
    groups, position = [], 0
    for names, getter, is_array in fields:
        groups.append((getter, position, len(names) if is_array else 0))
        position += len(names)
    size = position

    def extract(message: Any) -> np.ndarray:
        out = np.empty(size)
        for getter, at, length in groups:
            if length:
                value = getter(message)
                if len(value) != length:
                    raise ValueError("length changed")
                out[at:at + length] = value
            else:
                out[at] = getter(message)
        return out
    return extract
