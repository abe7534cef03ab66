"""``sensor_msgs/JointState`` read by joint name, for the bag reader (``mlnseq.sources.rosbag``): each message
by its own ``name`` list, so joints listed in another order, or two publishers sharing one topic with other
joints (an arm and a gripper), merge by name on the one clock instead of being read by position."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mlnseq.catalog.errors import BadInput
from mlnseq.sources.holds import Arrivals

JOINT_STATE = "sensor_msgs/msg/JointState"


class JointMismatch(ValueError):
    """A JointState message whose arrays do not match its joint names."""


class NewJoints(Exception):
    """A JointState topic names a joint after the clock started: the bag is read again knowing every joint."""


JOINT_FIELDS = ("position", "velocity", "effort")
MAX_PLANS = 256  # distinct joint lists of one topic whose column positions are kept


class JointState:
    """A ``sensor_msgs/JointState`` topic read by joint name: every (field, joint) that its messages carry is one
    feature, so publishers of other joints on one topic (an arm and a gripper) merge by name on the one clock;
    each message updates the joints it names, the others keep their last value. Joints are added as they come
    until the clock starts (``freeze``), then ordered by field (position, velocity, effort), first seen first.
    ``arrivals`` keeps when each column got its values (`update`), ``hold`` ns the longest a value is held."""

    def __init__(self, topic: str, columns: list[tuple[str, str]], hold: float = float("inf")):
        self.topic, self.columns, self.names = topic, list(columns), [f"{topic}/{f}/{j}" for f, j in columns]
        self.index = {column: k for k, column in enumerate(self.columns)}
        self.values, self.seen = np.zeros(len(self.columns)), np.zeros(len(self.columns), dtype=bool)
        self.arrivals = Arrivals(hold)  # a source per set of columns that messages set together
        self.sources: dict[tuple[int, ...], int] = {}
        self.frozen = False
        # (names, array sizes) -> ((field, columns) of each non-empty array, every column the message sets)
        self.plans: dict[tuple, tuple[list[tuple[str, np.ndarray]], np.ndarray]] = {}

    @property
    def complete(self) -> bool:
        return bool(self.seen.all())

    def __call__(self, message: Any) -> np.ndarray:
        return self.update(message, None)

    def update(self, message: Any, time: int | None) -> np.ndarray:
        """The values after ``message``, received at ``time`` ns (None: not kept in ``arrivals``)."""
        key = (tuple(message.name), *(len(getattr(message, field)) for field in JOINT_FIELDS))
        plan, source = self.plans.get(key) or self._plan(key)
        for field, columns in plan:
            self.values[columns] = getattr(message, field)
            self.seen[columns] = True
        if time is not None:
            self.arrivals.update(source, time)
        return self.values

    def _plan(self, key: tuple) -> tuple[list[tuple[str, np.ndarray]], int]:
        """Where each non-empty array of messages that name ``key[0]`` goes (new joints added, until frozen)."""
        joints, sizes = key[0], key[1:]
        if len(set(joints)) != len(joints):
            raise JointMismatch(f"JointState names a joint twice ({', '.join(joints)})")
        plan = []
        for field, size in zip(JOINT_FIELDS, sizes):
            if size and size != len(joints):
                raise JointMismatch(f"JointState {field} holds {size} values for {len(joints)} joint names")
            if size:
                plan.append((field, np.array([self._column(field, joint) for joint in joints], dtype=np.int64)))
        if len(self.plans) >= MAX_PLANS:  # joint lists that change message after message: keep memory bounded
            self.plans.clear()
        touched = tuple(sorted(int(c) for _, columns in plan for c in columns))
        if touched not in self.sources:
            self.sources[touched] = self.arrivals.add()
        self.plans[key] = plan, self.sources[touched]
        return self.plans[key]

    def _column(self, field: str, joint: str) -> int:
        if (field, joint) not in self.index:
            if self.frozen:
                raise NewJoints(self.topic)
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
        position = {old: new for new, old in enumerate(order)}
        self.sources = {tuple(sorted(position[c] for c in columns)): s for columns, s in self.sources.items()}
        return self.values

    def sources_of(self, column: int) -> tuple[int, ...]:
        """The sources (in ``arrivals``) of the messages that set ``column``."""
        return tuple(s for columns, s in self.sources.items() if column in columns)


def joint_columns(reader, path: Path) -> dict[str, list[tuple[str, str]]]:
    """Every JointState topic's (field, joint) columns, by field then first seen, from one pass over its messages."""
    connections = [c for c in reader.connections if c.msgtype == JOINT_STATE]
    states = {c.topic: JointState(c.topic, []) for c in connections}
    for connection, timestamp, raw in reader.messages(connections=connections):
        try:
            states[connection.topic](reader.deserialize(raw, connection.msgtype))
        except JointMismatch as error:
            raise BadInput(f"{path}: topic {connection.topic!r} at {(timestamp - reader.start_time) / 1e9:.6f} s: "
                           f"{error}") from None
    for state in states.values():
        state.freeze()  # columns ordered by field
    return {topic: state.columns for topic, state in states.items()}
