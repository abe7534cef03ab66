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
    joints = None  # each JointState topic's columns: the first bag's hold for the others, as its topics and rate do
    for path in bag_paths(Path(source)):
        try:
            with AnyReader([path], default_typestore=typestore) as reader:
                label_topic = options.label_topic if label is not Labels.NONE else None
                if label is Labels.OPTIONAL and label_topic not in reader.topics:
                    label_topic = None  # new recordings without their phases: unlabelled
                try:
                    recording = read_bag(reader, path, topics, rate, label_topic, options.unlabelled, joints)
                except _NewJoints:  # a second publisher's joints after the clock started: again, knowing them all
                    recording = read_bag(reader, path, topics, rate, label_topic, options.unlabelled,
                                         _joint_columns(reader, path))
        except BadInput:
            raise
        except Exception as error:  # rosbags raises its own and struct/EOF errors for truncated files
            text = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            raise BadInput(f"{path}: cannot read it as a ROS bag ({text[:160]})") from error
        topics, rate = tuple(recording.resolved["topics"]), recording.resolved["rate"]
        joints = recording.resolved["joints"]
        if columns.features:
            missing = [n for n in columns.features if n not in recording.features.columns]
            if missing:
                raise BadInput(f"{path}: no feature {missing[0]!r}; its features are "
                               f"{', '.join(recording.features.columns[:8])}")
            recording = dataclasses.replace(recording, features=recording.features.select(columns.features))
        recordings.append(recording)
    return recordings


def read_bag(reader, path: Path, topics: tuple[str, ...], rate: float | None, label_topic: str | None,
             unlabelled: str | None = None, joints: dict[str, list[tuple[str, str]]] | None = None) -> Recording:
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
    joint_states = {c.topic: _JointState(c.topic, (joints or {}).get(c.topic, []))
                    for c in connections if c.msgtype == JOINT_STATE}

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
            if topic in joint_states:  # read by joint name, not by position
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
            current[topic] = values
            if not getattr(extractors[topic], "complete", True):  # a JointState topic: once every joint has a value
                del current[topic]
        if row is None and candidates and all(t in current for t in candidates):
            current.update({t: state.freeze() for t, state in joint_states.items() if t in current})
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
        resolved={"topics": list(candidates), "rate": rate, "skipped_topics": skipped,
                  "joints": {topic: state.columns for topic, state in joint_states.items()}},
    )


class _JointMismatch(ValueError):
    """A JointState message whose arrays do not match its joint names."""


class _NewJoints(Exception):
    """A JointState topic names a joint after the clock started: the bag is read again knowing every joint."""


JOINT_FIELDS = ("position", "velocity", "effort")
MAX_PLANS = 256  # distinct joint lists of one topic whose column positions are kept


class _JointState:
    """A ``sensor_msgs/JointState`` topic read by joint name: every (field, joint) that its messages carry is one
    feature, so publishers of other joints on one topic (an arm and a gripper) merge by name on the one clock;
    each message updates the joints it names, the others keep their last value. Joints are added as they come
    until the clock starts (``freeze``), then ordered by field (position, velocity, effort), first seen first."""

    def __init__(self, topic: str, columns: list[tuple[str, str]]):
        self.topic, self.columns, self.names = topic, list(columns), [f"{topic}/{f}/{j}" for f, j in columns]
        self.index = {column: k for k, column in enumerate(self.columns)}
        self.values, self.seen = np.zeros(len(self.columns)), np.zeros(len(self.columns), dtype=bool)
        self.frozen = False
        self.plans: dict[tuple, list[tuple[str, np.ndarray]]] = {}  # (names, array sizes) -> (field, columns)

    @property
    def complete(self) -> bool:
        return bool(self.seen.all())

    def __call__(self, message: Any) -> np.ndarray:
        key = (tuple(message.name), *(len(getattr(message, field)) for field in JOINT_FIELDS))
        plan = self.plans.get(key) or self._plan(key)
        for field, columns in plan:
            self.values[columns] = getattr(message, field)
            self.seen[columns] = True
        return self.values

    def _plan(self, key: tuple) -> list[tuple[str, np.ndarray]]:
        """Where each non-empty array of messages that name ``key[0]`` goes (new joints added, until frozen)."""
        joints, sizes = key[0], key[1:]
        if len(set(joints)) != len(joints):
            raise _JointMismatch(f"JointState names a joint twice ({', '.join(joints)})")
        plan = []
        for field, size in zip(JOINT_FIELDS, sizes):
            if size and size != len(joints):
                raise _JointMismatch(f"JointState {field} holds {size} values for {len(joints)} joint names")
            if size:
                plan.append((field, np.array([self._column(field, joint) for joint in joints], dtype=np.int64)))
        if len(self.plans) >= MAX_PLANS:  # joint lists that change message after message: keep memory bounded
            self.plans.clear()
        self.plans[key] = plan
        return plan

    def _column(self, field: str, joint: str) -> int:
        if (field, joint) not in self.index:
            if self.frozen:
                raise _NewJoints(self.topic)
            self.index[(field, joint)] = len(self.columns)
            self.columns.append((field, joint))
            self.names.append(f"{self.topic}/{field}/{joint}")
            self.values, self.seen = np.append(self.values, 0.0), np.append(self.seen, False)
        return self.index[(field, joint)]

    def freeze(self) -> np.ndarray:
        """Order the columns by field and add no more; the values in that order."""
        order = sorted(range(len(self.columns)), key=lambda k: JOINT_FIELDS.index(self.columns[k][0]))
        self.columns = [self.columns[k] for k in order]
        self.names[:] = [self.names[k] for k in order]  # the same list read_bag holds
        self.index = {column: k for k, column in enumerate(self.columns)}
        self.values, self.seen, self.frozen, self.plans = self.values[order], self.seen[order], True, {}
        return self.values


def _joint_columns(reader, path: Path) -> dict[str, list[tuple[str, str]]]:
    """Every JointState topic's (field, joint) columns, by field then first seen, from one pass over its messages."""
    connections = [c for c in reader.connections if c.msgtype == JOINT_STATE]
    states = {c.topic: _JointState(c.topic, []) for c in connections}
    for connection, timestamp, raw in reader.messages(connections=connections):
        try:
            states[connection.topic](reader.deserialize(raw, connection.msgtype))
        except _JointMismatch as error:
            raise BadInput(f"{path}: topic {connection.topic!r} at {(timestamp - reader.start_time) / 1e9:.6f} s: "
                           f"{error}") from None
    for state in states.values():
        state.freeze()  # columns ordered by field
    return {topic: state.columns for topic, state in states.items()}


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
