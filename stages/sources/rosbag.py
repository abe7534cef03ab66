"""ROS bags as recordings, read with ``rosbags`` (no ROS install): a ROS 1 ``.bag``, a ROS 2 bag folder
(``metadata.yaml``; sqlite3 or MCAP storage), a bare ``.mcap``, or a folder of them, one episode each.

Numeric fields are flattened into features named ``TOPIC/FIELD/PATH`` (array elements by index, a
``sensor_msgs/JointState``'s by joint name; headers, text and byte arrays are left out). All topics are put
on one clock at ``rate`` Hz (default: the first topic's rate), starting when every topic has sent a message,
each tick holding each topic's last value at or before it (causal: never a value from the future). A frame's
time is seconds since the bag's first message, the bag's own record time. ``label_topic`` (std_msgs/String)
labels every tick with its last message. A tick holds a value for at most ``max_hold`` seconds: a channel (a topic,
or a JointState's joint) silent for longer leaves its ticks missing, and they are dropped; every channel that
stops before the end, starts after the beginning or goes silent is a note (``mlnseq.sources.holds``). Messages are
streamed, never all held.
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
from mlnseq.sources.holds import Arrivals, Channel, Clock, Held, hold_ns
from mlnseq.sources.joint_states import JOINT_STATE, JointMismatch, JointState, NewJoints, joint_columns
from mlnseq.sources.recording import Labels, Recording, TableColumns

BAG_SUFFIXES = (".bag", ".mcap")
STRING = "std_msgs/msg/String"
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
                without = label is not Labels.REQUIRED and label_topic is not None and label_topic not in reader.topics
                if without:  # recordings without their phases: unlabelled (collect says why if none has them)
                    listed = ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(reader.topics.items()))
                    without, label_topic = f"{path}: no topic {label_topic!r}; its topics are {listed}", None
                reading = Reading(topics, rate, label_topic, options.unlabelled, options.max_hold, columns.features)
                try:
                    recording = read_bag(reader, path, reading, joints)
                except NewJoints:  # a second publisher's joints after the clock started: again, knowing them all
                    recording = read_bag(reader, path, reading, joint_columns(reader, path))
        except BadInput:
            raise
        except Exception as error:  # rosbags raises its own and struct/EOF errors for truncated files
            text = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            raise BadInput(f"{path}: cannot read it as a ROS bag ({text[:160]})") from error
        if without and label is Labels.SOME:
            recording.resolved["unlabelled"] = without
        topics, rate = tuple(recording.resolved["topics"]), recording.resolved["rate"]
        joints = recording.resolved["joints"]
        recordings.append(recording)
    return recordings


@dataclasses.dataclass(frozen=True)
class Reading:
    """How a bag is read: its topics (empty: every topic with a numeric field), the clock's rate (None: the first
    topic's), the label topic, the class of ticks before its first message, the longest hold (s), the features."""

    topics: tuple[str, ...] = ()
    rate: float | None = None
    label_topic: str | None = None
    unlabelled: str | None = None
    max_hold: float = float("inf")
    features: tuple[str, ...] = ()


def read_bag(reader, path: Path, reading: Reading, joints: dict[str, list[tuple[str, str]]] | None = None) -> Recording:
    """One bag's frames; ticks before the label topic's first message are dropped, or labelled ``unlabelled``."""
    topics, label_topic = reading.topics, reading.label_topic
    listed = _check_topics(reader, path, topics, label_topic)
    candidates = list(topics) or sorted(t for t, info in reader.topics.items() if info.msgcount and t != label_topic)
    rate = reading.rate if reading.rate is not None else _rate_of(reader, path, candidates[0])
    wanted = set(candidates) | ({label_topic} if label_topic else set())
    clock = _Clock(reader, path, candidates, 1e9 / rate, label_topic, bool(topics), hold_ns(reading.max_hold))
    clock.joint_states = {c.topic: JointState(c.topic, (joints or {}).get(c.topic, []), clock.hold)
                          for c in reader.connections if c.topic in wanted and c.msgtype == JOINT_STATE}
    for connection, timestamp, raw in reader.messages(connections=[c for c in reader.connections if c.topic in wanted]):
        clock.message(connection, timestamp, raw)
    clock.finish(listed)
    return _recording(clock, path, dataclasses.replace(reading, rate=rate))


def _check_topics(reader, path: Path, topics: tuple[str, ...], label_topic: str | None) -> str:
    """Refuse an empty bag and a named topic it lacks or that sent nothing; the bag's topics, listed."""
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
    return listed


class _Clock:
    """The topics put on one clock, message by message: once every topic has sent a message, each tick holds
    each topic's last values at or before it (causal); the label topic's messages mark the ticks they label."""

    def __init__(self, reader, path: Path, candidates: list[str], period: float, label_topic: str | None,
                 named: bool, hold: float = float("inf")):
        self.reader, self.path, self.period, self.label_topic = reader, path, period, label_topic
        self.hold = hold  # ns a tick holds a value at most
        self.arrivals = Arrivals(hold)  # when each topic that is not a JointState got its values
        self.slots: dict[str, int] = {}  # its channel in ``arrivals``
        self.begin: int | None = None  # the first message of a topic read
        self.candidates = candidates  # the topics read; an unnamed topic without a numeric field is skipped
        self.named = named  # topics named by the user: one without a numeric field is an error
        self.start = reader.start_time
        self.extractors: dict[str, Callable[[Any], np.ndarray]] = {}
        self.names: dict[str, list[str]] = {}
        self.current: dict[str, np.ndarray] = {}  # each topic's values until the first tick
        self.last_time: dict[str, int] = {}
        self.skipped: list[str] = []
        self.row: np.ndarray | None = None  # the values every tick from the first on holds, topic after topic
        self.offsets: dict[str, tuple[int, int]] = {}
        self.frames: _Blocks | None = None
        self.label_changes: list[tuple[int, str | None]] = [(0, None)]  # (first tick, label)
        self.tick = 0
        self.clock0: int | None = None
        self.joint_states: dict[str, JointState] = {}  # JointState topics, read by joint name

    def message(self, connection, timestamp: int, raw: bytes) -> None:
        topic = connection.topic
        self._ticks_before(topic, timestamp)
        message = self.reader.deserialize(raw, connection.msgtype)
        if topic == self.label_topic:
            self.label_changes.append((self.tick, message.data))
            return
        if topic in self.skipped:
            return
        if self.begin is None:
            self.begin = timestamp
        if topic not in self.extractors:
            self._discover(topic, connection.msgtype, message)
        if topic in self.extractors:
            values = self._values(topic, message, timestamp)
            if self.row is not None:
                a, b = self.offsets[topic]
                self.row[a:b] = values
                return
            self.current[topic] = values
            if not getattr(self.extractors[topic], "complete", True):  # a JointState topic: once every joint has one
                del self.current[topic]
        if self.row is None and self.candidates and all(t in self.current for t in self.candidates):
            self._first_tick(timestamp)

    def _ticks_before(self, topic: str, timestamp: int) -> None:
        """Refuse a topic going back in time; the ticks before this message hold the values so far."""
        previous = self.last_time.get(topic)
        if previous is not None and timestamp < previous:
            raise BadInput(f"{self.path}: topic {topic!r} goes back in time at {(timestamp - self.start) / 1e9:.6f} s "
                           f"(after {(previous - self.start) / 1e9:.6f} s)")
        self.last_time[topic] = timestamp
        if self.row is not None:
            while self.clock0 + round(self.tick * self.period) < timestamp:
                self.frames.append(self.row)
                self.tick += 1

    def _discover(self, topic: str, msgtype: str, message: Any) -> None:
        """A topic's first message: its numeric fields and their feature names, or the topic skipped."""
        if topic in self.joint_states:  # by joint name, not by position
            self.names[topic], self.extractors[topic] = self.joint_states[topic].names, self.joint_states[topic]
            return
        fields = _leaves(message, topic, msgtype)
        if fields:
            self.names[topic] = [name for group, _, _ in fields for name in group]
            self.extractors[topic] = _extractor(fields)
            self.slots[topic] = self.arrivals.add()
        elif self.named:
            raise BadInput(f"{self.path}: topic {topic!r} ({msgtype}) has no numeric field")
        else:
            self.skipped.append(topic)
            self.candidates.remove(topic)

    def _values(self, topic: str, message: Any, timestamp: int) -> np.ndarray:
        try:
            if topic in self.joint_states:
                return self.joint_states[topic].update(message, timestamp)
            values = self.extractors[topic](message)
            self.arrivals.update(self.slots[topic], timestamp)
            return values
        except JointMismatch as error:
            raise BadInput(f"{self.path}: topic {topic!r} at {(timestamp - self.start) / 1e9:.6f} s: {error}") from None
        except ValueError:
            raise BadInput(f"{self.path}: topic {topic!r} changes its number of values at "
                           f"{(timestamp - self.start) / 1e9:.6f} s; a topic's fields must keep their length") from None

    def _first_tick(self, timestamp: int) -> None:
        """Every topic has sent a message: the clock starts now, with their values side by side."""
        self.current.update({t: state.freeze() for t, state in self.joint_states.items() if t in self.current})
        position = 0
        for t in self.candidates:
            self.offsets[t] = (position, position + len(self.current[t]))
            position += len(self.current[t])
        self.row = np.concatenate([self.current[t] for t in self.candidates])
        self.frames, self.clock0 = _Blocks(len(self.row)), timestamp

    def finish(self, listed: str) -> None:
        """After the last message: the ticks up to it, or an error if no tick has every topic's value."""
        if self.row is None:
            if not self.candidates:
                raise BadInput(f"{self.path}: no topic has a numeric field ({listed})")
            waiting = [t for t in self.candidates if t not in self.current]
            raise BadInput(f"{self.path}: topic {waiting[0]!r} sent no message, so no frame has every topic's value")
        end = max(self.last_time.values())
        while self.clock0 + round(self.tick * self.period) <= end:
            self.frames.append(self.row)
            self.tick += 1


def _recording(clock: _Clock, path: Path, reading: Reading) -> Recording:
    """The ticks as a recording: times, labels, and the features column by column; ticks where a feature read was
    held past ``max_hold`` are dropped, and every channel that stops, starts late or goes silent is a note."""
    n = clock.tick
    times = clock.clock0 + np.round(np.arange(n) * clock.period).astype(np.int64)
    labels = np.full(n, None, dtype=object)
    for (first, name), (after, _) in zip(clock.label_changes, [*clock.label_changes[1:], (n, None)]):
        labels[first:after] = name
    all_names = [name for t in clock.candidates for name in clock.names[t]]
    wanted = list(reading.features) or all_names
    missing = [name for name in wanted if name not in all_names]
    if missing:
        raise BadInput(f"{path}: no feature {missing[0]!r}; its features are {', '.join(all_names[:8])}")
    held = Held(wanted, [_channel(clock, name) for name in wanted],
                Clock(times, clock.begin, max(clock.last_time.values()), clock.start, clock.period), reading.max_hold)
    keep = held.keep()
    if reading.label_topic:
        if reading.unlabelled is not None:
            labels[labels == None] = reading.unlabelled  # noqa: E711
        if not (labels != None).any():  # noqa: E711
            raise BadInput(f"{path}: --label-topic {reading.label_topic} sends its first message after the last frame")
        keep &= labels != None  # noqa: E711
    if not keep.any():
        why = next((note.split(": ", 1)[1] for note in held.notes(path.name) if "missing" in note), "")
        raise BadInput(f"{path}: no frame has a value of every feature within --max-hold {reading.max_hold:g} s "
                       f"({why}): read fewer --topics or --features, or hold longer with --max-hold")
    rows = np.flatnonzero(keep)
    index = {name: i for i, name in enumerate(all_names)}
    columns = {name: clock.frames.column(index[name])[keep] for name in wanted}  # a column at a time, no third copy
    clock.frames = None
    features = check_features(pl.DataFrame(columns), path, "{file} frame {row}", pl.Series(rows))
    return Recording(
        path=path, features=features, episode=pl.Series([path.stem if path.is_file() else path.name] * len(rows)),
        time=pl.Series((times[keep] - clock.start) / 1e9),
        label=pl.Series("label", labels[keep].tolist(), dtype=pl.String) if reading.label_topic else None,
        row=pl.Series(rows), where="{file} frame {row}",
        resolved={"topics": list(clock.candidates), "rate": reading.rate, "skipped_topics": clock.skipped,
                  "joints": {topic: state.columns for topic, state in clock.joint_states.items()},
                  "notes": held.notes(path.name), "clock_start": clock.start},
    )


def _channel(clock: _Clock, name: str) -> Channel:
    """Where feature ``name``'s arrivals are kept: its JointState's column, or its topic."""
    topic = next(t for t in clock.candidates if name in clock.names[t])
    state = clock.joint_states.get(topic)
    if state is not None:
        return Channel(topic, state.arrivals, state.sources_of(state.names.index(name)))
    return Channel(topic, clock.arrivals, (clock.slots[topic],))


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
                by_joint = joints is not None and len(joints) == value.size and len(path) == 1
                labels = joints if by_joint else range(value.size)
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
