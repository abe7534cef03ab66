"""echo: a ROS 2 topic's messages, heard over DDS (no ROS install), as the rows `rostopic echo -p` prints on ROS 1,
which `mlnseq stream` reads: ``mlnseq echo /joint_states | mlnseq stream MODEL``.

The first line is the header: ``%time``, then ``field.`` and each numeric or text field's path (an array's elements
by index, ``field.position0``; a nested field by dots, ``field.pose.position.x``); the header stamp is one column of
ns, ``field.header.stamp``. ``%time`` is the sample's source timestamp (ns), the time it was sent. The topic's
type and reliability are those its first publisher offers (``--qos`` overrides), read with the message definitions
of ``--distro``. A message whose fields differ from the first's (a JointState of another length) cannot be a row
under that header: it is skipped and said on stderr.
"""

from __future__ import annotations

import csv
import io
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from mlnseq.catalog.errors import BadInput, check_choice
from mlnseq.catalog.methods import member
from mlnseq.catalog.stopping import stop_on_signals
from mlnseq.dds.domain import QosChoice
from mlnseq.recognition import rostopic

WAIT_S = 0.1  # the longest a wait for samples lasts before the stop flag is looked at again


@dataclass(frozen=True)
class EchoOptions:
    """Options of `mlnseq echo`."""

    topic: str
    count: int | None = None  # stop after this many messages
    distro: str | None = None  # default: ROS_DISTRO where it is a ROS 2 one, else humble
    qos: QosChoice | str = QosChoice.AUTO

    def __post_init__(self) -> None:
        object.__setattr__(self, "qos", member(QosChoice, self.qos))

    def validate(self) -> None:
        if not self.topic.strip("/ ") or " " in self.topic:
            raise BadInput(f"TOPIC {self.topic!r}: not a ROS topic name")
        if self.count is not None and self.count < 1:
            raise BadInput(f"--count {self.count}: at least 1 message")
        check_choice("qos", self.qos, tuple(QosChoice))


@dataclass
class EchoSummary:
    messages: int = 0
    skipped: int = 0
    type_name: str = ""


def fields(message: Any, path: str = "field") -> list[tuple[str, Any]]:
    """A message's columns as `rostopic echo -p` names them, with their values (the header stamp in ns)."""
    out: list[tuple[str, Any]] = []
    for name in message.get_fields_and_field_types():
        value = getattr(message, name)
        column = f"{path}.{name}"
        if column == "field.header":
            out += [("field.header.stamp", rostopic.message_time(message)), ("field.header.frame_id", value.frame_id)]
        elif isinstance(value, (list, tuple)):
            for k, item in enumerate(value):
                out += fields(item, f"{column}{k}") if hasattr(item, "get_fields_and_field_types") else [
                    (f"{column}{k}", item)]
        elif hasattr(value, "get_fields_and_field_types"):
            out += fields(value, column)
        elif not isinstance(value, (bytes, bytearray)):  # a uint8[N] array comes as bytes: left out, as collect did
            out.append((column, value))
    return out


def csv_line(values: list[Any]) -> str:
    """One row: floats in full (repr), booleans as 1 and 0 (numbers, as collect read them), text quoted as CSV."""
    text = io.StringIO()
    csv.writer(text, lineterminator="").writerow(
        [int(v) if isinstance(v, bool) else repr(v) if isinstance(v, float) else v for v in values])
    return text.getvalue()


def run(options: EchoOptions, emit: Callable[[str], None], warn: Callable[[str], None],
        stop: threading.Event | None = None) -> EchoSummary:
    """Print the topic's messages through ``emit`` until SIGINT or SIGTERM (or ``stop``), or --count of them."""
    from mlnseq.dds import domain, require, types

    options.validate()
    require()
    distro = options.distro or types.default_distro()
    message_types = types.MessageTypes(distro)
    participant = domain.Participant(distro, "mlnseq_echo")
    subscriptions = domain.Subscriptions(participant, message_types, [options.topic], options.qos,
                                         lambda topic, text: warn(f"error: {text}"))
    with stop_on_signals(stop) as heard:
        return _echo(options, subscriptions, participant.domain_id, emit, warn, heard.stop)


def _echo(options: EchoOptions, subscriptions: Any, domain_id: int, emit: Callable[[str], None],
          warn: Callable[[str], None], stop: threading.Event) -> EchoSummary:
    """The rows, under the first message's header, until ``stop`` or --count."""
    summary, header = EchoSummary(), None
    while not stop.is_set() and summary.messages != options.count:
        for made in subscriptions.discover():
            summary.type_name = made.type_name
            warn(f"echo: {made.describe()} on DDS domain {domain_id}")
        for _, message, sent in subscriptions.take(WAIT_S):
            columns = fields(message)
            names = ["%time", *(name for name, _ in columns)]
            if header is None:
                header = names
                emit(",".join(header))
            if names != header:
                summary.skipped += 1
                if summary.skipped == 1:
                    warn(f"error: a {options.topic} message has {len(names) - 1} fields where the first had "
                         f"{len(header) - 1}: skipped, as are the others like it (counted at the end)")
                continue
            emit(csv_line([sent, *(value for _, value in columns)]))
            summary.messages += 1
            if summary.messages == options.count:
                break
    return summary
