"""A DDS participant as a ROS 2 node's rmw_cyclonedds makes it: the domain ``ROS_DOMAIN_ID``, the discovery its
distro's environment asks for, ROS topic names as DDS topics (``/joint_states`` is ``rt/joint_states``), ROS's QoS
profiles, and subscriptions made as publishers are discovered, each of the type and reliability its first
publisher offers (as `ros2 topic echo` adapts to the publishers it finds), or for a model's topics the first type
holding the model's fields (a stray publisher of another type is said, and never subscribed).

Discovery, as rmw_cyclonedds configures Cyclone: up to Humble, ``ROS_LOCALHOST_ONLY=1`` binds the loopback
interface; from Iron on, ``ROS_AUTOMATIC_DISCOVERY_RANGE`` (SUBNET, LOCALHOST, OFF, SYSTEM_DEFAULT; LOCALHOST where
it is unset and ``ROS_LOCALHOST_ONLY=1``) and ``ROS_STATIC_PEERS``. ``CYCLONEDDS_URI`` (a file or XML) is read after
them, as Cyclone and rmw_cyclonedds read it.
"""

from __future__ import annotations

import heapq
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from mlnseq.catalog.errors import BadInput
from mlnseq.dds.types import MessageTypes, ros_type_name
from mlnseq.recognition import rostopic

TOPIC_PREFIX = "rt"  # ROS 2 topics in DDS: rt/joint_states (rmw's namespace_prefix.hpp)
MAX_DOMAIN_ID = 232  # Cyclone's port mapping: 7400 + 250 x domain stays below 65536
LOCALHOST_ONLY_DISTROS = ("dashing", "eloquent", "foxy", "galactic", "humble")  # later ones: the discovery range
QUEUE = 1000  # samples a reader or writer holds: 10 s at 100 Hz, as the ROS 1 node's queues


class QosChoice(StrEnum):
    """``--qos``: the subscriptions' reliability."""

    AUTO = "auto"  # as the topic's first publisher offers it: reliable or best effort
    RELIABLE = "reliable"  # ROS's default profile
    BEST_EFFORT = "best-effort"  # ROS's sensor-data profile; matches every publisher


class DiscoveryRange(StrEnum):
    """``ROS_AUTOMATIC_DISCOVERY_RANGE`` (Iron on)."""

    SUBNET = "SUBNET"
    LOCALHOST = "LOCALHOST"
    OFF = "OFF"
    SYSTEM_DEFAULT = "SYSTEM_DEFAULT"


def topic_name(topic: str) -> str:
    """A ROS 2 topic's DDS name: ``/joint_states`` -> ``rt/joint_states`` (a relative name is in ``/``)."""
    return f"{TOPIC_PREFIX}/{topic.strip('/')}"


def domain_id(environ: Mapping[str, str]) -> int:
    """``ROS_DOMAIN_ID``, 0 where unset, as ROS 2 reads it."""
    text = environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    if not text.isdigit() or int(text) > MAX_DOMAIN_ID:
        raise BadInput(f"ROS_DOMAIN_ID {text!r}: a domain id is a whole number from 0 to {MAX_DOMAIN_ID} "
                       "(ROS 2 recommends 0 to 101)")
    return int(text)


def discovery_config(distro: str, environ: Mapping[str, str]) -> str:
    """The Cyclone configuration a ROS 2 node of ``distro`` makes from the environment, then CYCLONEDDS_URI's."""
    localhost_only = environ.get("ROS_LOCALHOST_ONLY", "").strip() == "1"
    if distro in LOCALHOST_ONLY_DISTROS:
        fragment = ("<CycloneDDS><Domain><General><Interfaces><NetworkInterface address=\"127.0.0.1\"/></Interfaces>"
                    "</General></Domain></CycloneDDS>") if localhost_only else ""
    else:
        fragment = _ranged(_discovery_range(environ, localhost_only), environ.get("ROS_STATIC_PEERS", ""))
    return ",".join(part for part in (fragment, environ.get("CYCLONEDDS_URI", "").strip()) if part)


def _discovery_range(environ: Mapping[str, str], localhost_only: bool) -> DiscoveryRange:
    text = environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper()
    if not text:
        return DiscoveryRange.LOCALHOST if localhost_only else DiscoveryRange.SUBNET
    try:
        return DiscoveryRange(text)
    except ValueError:
        raise BadInput(f"ROS_AUTOMATIC_DISCOVERY_RANGE {text!r}: choose one of "
                       f"{', '.join(DiscoveryRange)}") from None


def _ranged(scope: DiscoveryRange, static_peers: str) -> str:
    """rmw_cyclonedds' configuration for a discovery range (Iron on)."""
    if scope is DiscoveryRange.SYSTEM_DEFAULT:
        return ""
    peers = [peer.strip() for peer in static_peers.split(";") if peer.strip() and scope is not DiscoveryRange.OFF]
    if scope is DiscoveryRange.LOCALHOST:
        peers.insert(0, "localhost")
    general = "" if scope is DiscoveryRange.SUBNET else "<General><AllowMulticast>false</AllowMulticast></General>"
    if scope is DiscoveryRange.OFF:  # a tag no other process has: nothing is discovered
        discovery = f"<ParticipantIndex>none</ParticipantIndex><Tag>ros_discovery_off_{os.getpid()}</Tag>"
    else:
        discovery = "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
    if peers:
        discovery += "<Peers>" + "".join(f"<Peer address=\"{peer}\"/>" for peer in peers) + "</Peers>"
    return f"<CycloneDDS><Domain>{general}<Discovery>{discovery}</Discovery></Domain></CycloneDDS>"


def profile(reliable: bool, depth: int = QUEUE, writer: bool = False) -> Any:
    """A ROS QoS profile as rmw_cyclonedds sets it: reliable or best effort, volatile, keep last ``depth``, no
    autodispose; plain CDR (XCDR1) written, XCDR1 or 2 read."""
    from cyclonedds.core import Policy, Qos

    return Qos(Policy.Reliability.Reliable(max_blocking_time=10**8) if reliable else Policy.Reliability.BestEffort,
               Policy.Durability.Volatile, Policy.History.KeepLast(depth),
               Policy.WriterDataLifecycle(autodispose=False),
               Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=not writer))


class Participant:
    """One DDS participant on ROS 2's domain, with the discovery its environment asks for; it sees publications."""

    def __init__(self, distro: str, name: str, environ: Mapping[str, str] = os.environ):
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
        from cyclonedds.core import DDSException, Policy, Qos, WaitSet
        from cyclonedds.domain import Domain, DomainParticipant

        self.domain_id, config = domain_id(environ), discovery_config(distro, environ)
        try:
            self.domain = Domain(self.domain_id, config) if config else None
            self.participant = DomainParticipant(self.domain_id, qos=Qos(Policy.EntityName(name)))
        except DDSException as error:
            raise BadInput(f"Cyclone DDS refused its configuration (the ROS_* variables, CYCLONEDDS_URI): "
                           f"{error}") from None
        self.publications = BuiltinDataReader(self.participant, BuiltinTopicDcpsPublication)
        self.waitset = WaitSet(self.participant)
        self.waitset.attach(self._arrived(self.publications))  # a new publisher wakes the wait as a sample does
        self.topics: dict[str, Any] = {}
        self.participants: Any = None  # the participants discovered, read when a publisher is named

    def topic(self, topic: str, kind: type) -> Any:
        from cyclonedds.topic import Topic

        if topic not in self.topics:
            self.topics[topic] = Topic(self.participant, topic_name(topic), kind)
        return self.topics[topic]

    def writer(self, topic: str, kind: type) -> Any:
        """A reliable writer on ``topic`` (ROS's default profile, deeper)."""
        from cyclonedds.pub import DataWriter

        return DataWriter(self.participant, self.topic(topic, kind), qos=profile(True, writer=True))

    def reader(self, topic: str, kind: type, reliable: bool) -> Any:
        from cyclonedds.sub import DataReader

        reader = DataReader(self.participant, self.topic(topic, kind), qos=profile(reliable))
        self.waitset.attach(self._arrived(reader))
        return reader

    @staticmethod
    def _arrived(reader: Any) -> Any:
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState

        return ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any)

    def describe(self, publication: Any) -> str:
        """A discovered publisher in words: its participant's name where it gives one, and its writer's GUID."""
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsParticipant
        from cyclonedds.core import Policy

        if self.participants is None:
            self.participants = BuiltinDataReader(self.participant, BuiltinTopicDcpsParticipant)
        for known in self.participants.read(N=256):
            if known.key == publication.participant_key and Policy.EntityName in known.qos:
                return f"its writer {publication.key} (participant {known.qos[Policy.EntityName].name!r})"
        return f"its writer {publication.key} (participant {publication.participant_key})"

    def new_publications(self) -> list[Any]:
        """The publications discovered since the last call (their topic, type and QoS)."""
        return [p for p in self.publications.take(N=256) if getattr(p.sample_info, "valid_data", True)]

    def wait(self, seconds: float) -> None:
        """Until a reader has samples, or ``seconds``."""
        from cyclonedds.util import duration

        self.waitset.wait(duration(seconds=seconds))

    def acknowledged(self, writers: tuple[Any, ...], seconds: float) -> None:
        """Wait (at most ``seconds`` in all) until the writers' reliable readers have acknowledged every sample."""
        from cyclonedds.core import DDSException
        from cyclonedds.util import duration

        deadline = time.monotonic() + seconds
        for writer in writers:
            try:
                writer.wait_for_acks(duration(seconds=max(deadline - time.monotonic(), 0)))
            except DDSException:  # timed out: a reader that went away or cannot keep up
                return


def offers_reliable(publication: Any) -> bool:
    from cyclonedds.core import Policy

    reliability = publication.qos[Policy.Reliability] if Policy.Reliability in publication.qos else None
    return not isinstance(reliability, type(Policy.Reliability.BestEffort))


@dataclass
class Subscription:
    """One of the wanted topics, subscribed: its ROS type, whether reliable, its reader."""

    topic: str
    type_name: str
    reliable: bool
    reader: Any

    def describe(self) -> str:
        return f"{self.topic} ({self.type_name}, {'reliable' if self.reliable else 'best effort'})"


class Subscriptions:
    """The wanted ROS topics, each subscribed once its first publisher is discovered, as its type and with the QoS
    chosen (``--qos``); a publisher that cannot be read is one line through ``say(topic, text)``. With ``needs``
    (topic -> the top-level fields its features are read from), a topic is read only as a type holding numbers in
    those fields: a publisher of another type (a stray std_msgs/String on /joint_states) is one line through
    ``note``, naming it, and the topic is subscribed as the type that holds them when its publisher appears."""

    def __init__(self, participant: Participant, types: MessageTypes, topics: list[str], qos: QosChoice,
                 say: Callable[[str, str], None], needs: Mapping[str, set[str]] | None = None,
                 note: Callable[[str], None] | None = None):
        self.participant, self.types, self.qos, self.say = participant, types, qos, say
        self.needs, self.note = needs, note or (lambda text: say("", text))
        self.wanted = {topic_name(t): t for t in topics}
        self.subscribed: dict[str, Subscription] = {}
        self.refused: set[tuple[str, str]] = set()  # (topic, what was said): said once

    def discover(self) -> list[Subscription]:
        """Subscribe to the wanted topics whose publishers appeared; the new subscriptions."""
        made = []
        for publication in self.participant.new_publications():
            topic = self.wanted.get(publication.topic_name)
            if topic is not None:
                made += self._publication(topic, publication)
        return made

    def _publication(self, topic: str, publication: Any) -> list[Subscription]:
        type_name = ros_type_name(publication.type_name) or publication.type_name
        reliable = offers_reliable(publication)
        if type_name in self.types and self.needs is not None:
            missing = self.needs.get(topic, set()) - self.types.numeric_fields(type_name)
            if missing:
                if (topic, str(publication.key)) not in self.refused:
                    self.refused.add((topic, str(publication.key)))
                    self.note(f"note: a publisher on {topic} sends {type_name}, which holds no "
                              f"{', '.join(sorted(missing))} for the model's features: "
                              f"{self.participant.describe(publication)} is not read; {topic} is read as the type "
                              "that holds them")
                return []
        known = self.subscribed.get(topic)
        if known is not None:
            if known.type_name != type_name:
                self._refuse(topic, f"a publisher on {topic} sends {type_name}, not {known.type_name} (the type of "
                             "its first publisher, subscribed to): its messages are not read")
            elif known.reliable and not reliable:
                self._refuse(topic, f"a best-effort publisher on {topic} does not match the reliable subscription "
                             "made for the first: run with --qos best-effort")
            return []
        if type_name not in self.types:
            self._refuse(topic, f"{topic} sends {type_name}, not a message type of ROS 2 {self.types.distro} "
                         "(rosbags' typestore; check --distro)")
            return []
        wanted = reliable if self.qos is QosChoice.AUTO else self.qos is QosChoice.RELIABLE
        if wanted and not reliable:
            self._refuse(topic, f"the publisher on {topic} is best effort and --qos reliable does not match it: "
                         "run with --qos best-effort or auto")
        subscription = Subscription(topic, type_name, wanted,
                                    self.participant.reader(topic, self.types.get(type_name), wanted))
        self.subscribed[topic] = subscription
        return [subscription]

    def _refuse(self, topic: str, text: str) -> None:
        if (topic, text) not in self.refused:
            self.refused.add((topic, text))
            self.say(topic, text)

    def take(self, seconds: float) -> list[tuple[str, Any, int]]:
        """Every sample that has arrived (waiting up to ``seconds`` for one): (topic, message, source time in ns),
        in the order of their times (header stamps, else the source timestamps)."""
        self.participant.wait(seconds)
        taken = [self._samples(subscription) for subscription in self.subscribed.values()]
        # merged by time, each topic's own order kept (a message older than its topic's last is the feed's to say)
        return list(heapq.merge(*taken, key=lambda item: rostopic.message_time(item[1]) or item[2]))

    def _samples(self, subscription: Subscription) -> list[tuple[str, Any, int]]:
        """A subscription's samples; a batch whose bytes its type cannot read is said, and dropped."""
        try:
            samples = subscription.reader.take(N=QUEUE)
        except Exception as error:  # the type's deserializer on bytes of another layout: struct, index errors
            self.say(subscription.topic, f"{subscription.topic} sent a message {subscription.type_name} cannot read "
                     f"({type(error).__name__}: {error}); the messages taken with it are dropped")
            return []
        return [(subscription.topic, sample, int(sample.sample_info.source_timestamp))
                for sample in samples if sample.sample_info.valid_data]
