"""A model trained on ROS topics, fed live messages: `LiveRecognizer` puts each topic's messages on the
model's clock as collect put the bags on it (stages/recognition/rostopic.py's `HoldLast`) and runs the same
`Recognizer` as predict and stream on every tick. `mlnseq stream` (`rostopic echo -p` on stdin), the ROS 1
node (`mlnseq ros`) and a ROS 2 node all call it.

Faults a live feed brings are handled here, once for every node: a topic silent past ``max_hold`` seconds leaves
its ticks missing, and they are skipped with a note (as collect drops them); time that jumps back by more than a
frame (a bag replayed in a loop) ends the episode, whose held frames are decided, and starts a new one with a note;
`MessageFeed` keeps a bounded queue between a client library's callbacks and the recogniser (the oldest messages
dropped first, counted and said) and drains it on shutdown, deciding every frame it holds.

The model remembers its topics, rate and hold (its manifest's ``reading``, written by collect --env rosbag).
"""

from __future__ import annotations

import collections
import json
import math
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from mlnseq.catalog.errors import BadInput
from mlnseq.recognition.recognizer import Prediction, Recognizer
from mlnseq.recognition import rostopic
from mlnseq.sources.holds import MAX_HOLD_S

RATE_PROBE = 20  # messages of the clock topic whose median period gives the feed's rate
RATE_FACTOR = 2.0  # a feed faster or slower than the model's clock by more than this is said once
QUEUE = 1000  # messages a MessageFeed holds for the recogniser: 10 s at 100 Hz; the oldest dropped beyond
DROPS_SAID_EVERY_S = 10.0  # after the first, dropped messages are said at most this often


@dataclass(frozen=True)
class LiveFrame:
    """One tick of the model's clock: its time (ns, the messages' clock) and its recognition."""

    time: int
    prediction: Prediction

    lag: int = 0  # frames the model waited before deciding this one
    episode: int = 0  # a new one each time the feed's time jumps back
    start: int = 0  # the episode's first message (ns, the messages' clock): where its recording starts

    def record(self, classes: list[str]) -> dict[str, Any]:
        """The frame as stream writes it: episode, frame, time (s from the episode's first message, as predict counts
        from a bag's start), stamp (s, the messages' clock), class, probabilities, lag (and why, explained)."""
        p = self.prediction
        line = {"episode": self.episode, "frame": p.frame, "time": (self.time - self.start) / 1e9,
                "stamp": self.time / 1e9, "class": p.name,
                "probabilities": dict(zip(classes, p.probabilities.tolist())), "lag": self.lag}
        if p.why is not None:
            line["why"] = p.why
        return line

    def json(self, classes: list[str]) -> str:
        return encoded(self.record(classes))


def encoded(line: dict[str, Any]) -> str:
    """A line as JSON; its ``why``, last, as the explainer encoded it (the same text as json.dumps, made once per
    formula term)."""
    why = line.get("why")
    if why is None or not hasattr(why, "json"):
        return json.dumps(line)
    return f'{json.dumps({k: v for k, v in line.items() if k != "why"})[:-1]}, "why": {why.json}}}'


def needed_fields(model: Recognizer) -> dict[str, set[str]]:
    """Each of the model's topics: the top-level message fields its features are read from (``position`` for
    ``/joint_states/position/panda_joint1``), which a message type must hold for the topic to be read as it."""
    topics, _ = model_topics(model)
    needs: dict[str, set[str]] = {topic: set() for topic in topics}
    for topic, slots in rostopic.features_by_topic(model.features, topics).items():
        prefix = len(topic.rstrip("/")) + 1
        needs[topic] |= {model.features[i][prefix:].split("/", 1)[0] for i in slots}
    return needs


def prepared(path: Any, warn: Callable[[str], None], decode: str | None = None, explain: int = 0) -> Recognizer:
    """A model file loaded for a live feed: decoded with ``decode`` (default: the model's; an offline decoder is said
    to filter), each decided frame carrying ``why``, its ``explain`` largest terms (0: none)."""
    model = Recognizer.load(path)
    if decode is not None:
        model.decoded_with(decode)
    if model.decoding.decoder.offline:
        warn(f"note: {model.decode} needs a whole recording; live, the filter decodes with the same factors")
    if explain:
        model.explain_steps(explain)
    return model


def model_topics(model: Recognizer) -> tuple[list[str], float]:
    """The topics and rate the model's frames were read with; refuses a model not read from ROS bags."""
    reading = model.manifest.reading or {}
    if reading.get("env") != "rosbag" or not reading.get("topics") or not reading.get("rate"):
        raise BadInput(f"the model's frames were read with --env {reading.get('env') or '?'}, not from ROS bags, so it "
                       "knows no topics: feed it frames by feature name (JSON or CSV lines)")
    return list(reading["topics"]), float(reading["rate"])


def model_hold(model: Recognizer) -> float:
    """The longest hold (s) the model's frames were read with: its reading's ``max_hold`` (null: no bound)."""
    reading = model.manifest.reading or {}
    if "max_hold" not in reading:
        return MAX_HOLD_S  # a model from before the hold was kept
    return math.inf if reading["max_hold"] is None else float(reading["max_hold"])


class LiveRecognizer:
    """Messages in (topic, time in ns, feature values), recognised ticks out. Bad messages raise BadInput and
    change nothing; ``warn`` hears the notes (a feed's rate far from the model's, late messages, silent topics,
    time jumping back). ``max_hold``: seconds a tick holds a silent topic's values (default: the model's)."""

    def __init__(self, model: Recognizer, warn: Callable[[str], None], max_hold: float | None = None):
        self.model, self.warn = model, warn
        self.topics, self.rate = model_topics(model)
        self.max_hold = model_hold(model) if max_hold is None else max_hold
        self.slots = rostopic.features_by_topic(model.features, self.topics)
        self.probe: list[int] | None = []  # the clock topic's first message times, until its rate is known
        self.said: set[str] = set()
        self.lag = model.lag if model.decoding.decoder.lagged else 0
        self.episode = 0
        self._start_episode()

    def _start_episode(self) -> None:
        self.clock = rostopic.HoldLast(self.slots, len(self.model.features), self.rate, self.max_hold)
        self.times: dict[int, int] = {}  # tick time of each frame not decided yet (a lagged decoder: lag + 1)
        self.first: int | None = None  # the episode's first message
        self.silent: list[str] = []  # the topics whose silence is skipping ticks now
        self.skipped = 0  # ticks skipped in this silence

    def message(self, topic: str, time: int, values: Mapping[str, float]) -> list[LiveFrame]:
        """The ticks this message closes, recognised; then its values are held. A message more than a frame older
        than its topic's previous one ends the episode (its frames decided) and starts the next."""
        vector = self._vector(topic, time, values)
        previous = self.clock.seen.get(topic)
        out = self._jump(topic, previous, time) if previous is not None and previous - time > self.clock.period else []
        started = self.clock.clock0 is not None
        ticks = self.clock.push(topic, time, vector)
        self.first = time if self.first is None else self.first
        if not started and self.clock.clock0 is not None and self.clock.clock0 - self.first > self.max_hold * 1e9:
            self.warn(f"note: the clock starts at {time / 1e9:.3f} s, once every topic has sent a message ({topic} "
                      f"came {(time - self.first) / 1e9:.3f} s after the first): no frame before it")
        if topic == self.topics[0]:
            self._probe(time)
        if topic in self.clock.late and topic not in self.said:
            self.said.add(topic)
            self.warn(f"note: a {topic} message arrived after a later tick was answered; it counts from the next tick")
        return out + self._recognise(ticks)

    def _vector(self, topic: str, time: int, values: Mapping[str, float]) -> np.ndarray:
        if topic not in self.slots:
            raise BadInput(f"topic {topic!r} is not one the model was trained on ({', '.join(self.topics)})")
        if not time:
            raise BadInput(f"a {topic} message has no time (header stamp 0 and no receive time)")
        names = [self.model.features[i] for i in self.slots[topic]]
        missing = [name for name in names if name not in values]
        if missing:
            raise BadInput(f"a {topic} message lacks the model's feature {', '.join(map(repr, missing[:3]))}"
                           f"{' ...' if len(missing) > 3 else ''}")
        vector = np.array([values[name] for name in names], dtype=np.float64)
        if not np.isfinite(vector).all():
            bad = names[int(np.flatnonzero(~np.isfinite(vector))[0])]
            raise BadInput(f"a {topic} message's feature {bad!r} is {values[bad]}, not a finite number")
        return vector

    def _jump(self, topic: str, previous: int, time: int) -> list[LiveFrame]:
        """Time went back: the episode's frames decided, then a new episode (if this one answered any tick)."""
        out = self.finish() if self.clock.tick else []
        if self.clock.tick:
            self.episode += 1
            self.warn(f"note: {topic} goes back {(previous - time) / 1e9:.3f} s in time (to {time / 1e9:.3f} s, a bag "
                      f"replayed in a loop?): episode {self.episode} starts, the frames before it decided")
        self.model.reset()
        self._start_episode()
        return out

    def finish(self) -> list[LiveFrame]:
        """The ticks up to the last message, once the feed has ended, and a lagged decoder's pending frames."""
        return self._recognise(self.clock.finish()) + self._decided(self.model.finish())

    def _recognise(self, ticks: Iterable[tuple[int, np.ndarray]]) -> list[LiveFrame]:
        """Each tick stepped, but a tick with a silent topic's values missing, which is skipped; the frames a step
        decides (itself, or with a lag L the frame L ticks back) answered."""
        out = []
        for time, row in ticks:
            if np.isnan(row).any():
                self._silence(time, row)
                continue
            if self.silent:
                self.warn(f"note: {', '.join(self.silent)} sent again: {self.skipped:,} frames skipped "
                          f"({time / 1e9:.3f} s)")
                self.silent, self.skipped = [], 0
            self.times[self.model.next_frame] = time
            out += self._decided(self.model.step(row).final)
        return out

    def _silence(self, time: int, row: np.ndarray) -> None:
        if not self.silent:
            self.silent = [topic for topic, slots in self.slots.items() if np.isnan(row[slots]).any()]
            self.warn(f"note: {', '.join(self.silent)} sent nothing for over {self.max_hold:g} s (--max-hold): the "
                      f"frames from {time / 1e9:.3f} s are skipped until it sends again")
        self.skipped += 1

    def _decided(self, predictions: Iterable[Prediction]) -> list[LiveFrame]:
        return [LiveFrame(self.times.pop(p.frame), p, self.lag, self.episode, self.first or 0) for p in predictions]

    def _probe(self, time: int) -> None:
        if self.probe is None:
            return
        self.probe.append(time)
        if len(self.probe) < RATE_PROBE:
            return
        steps = np.diff(np.asarray(self.probe, dtype=np.int64))
        steps = steps[steps > 0]
        self.probe = None
        if not steps.size:
            return
        feed = 1e9 / float(np.median(steps))
        if not 1 / RATE_FACTOR <= feed / self.rate <= RATE_FACTOR:
            self.warn(f"warning: {self.topics[0]} arrives at {feed:.4g} Hz, the model's clock is {self.rate:.4g} Hz "
                      f"(more than {RATE_FACTOR:g}x apart): each frame holds the last message at its tick, as "
                      "collect read the bags")


def echo_topic(live: LiveRecognizer) -> str:
    """The topic a `rostopic echo -p` feed stands for: the model's only one. One echo shows one topic, and a frame
    needs every topic's values, so a model of several topics is refused."""
    if len(live.topics) > 1:
        raise BadInput(f"the model reads {len(live.topics)} topics ({', '.join(live.topics)}) and `rostopic echo -p` "
                       "shows one: run the node `mlnseq ros MODEL`, which subscribes to all of them")
    return live.topics[0]


def feed_echo(live: LiveRecognizer, topic: str, lines: Iterable[tuple[int, str | BadInput]],
              header: str) -> Iterable[tuple[int, LiveFrame | BadInput]]:
    """`rostopic echo -p` rows (numbered lines after ``header``) through ``live``: every recognised tick, or
    the error a row makes (naming its line), in order; the last ticks once the rows end."""
    echo = rostopic.EchoCsv(header, topic, [live.model.features[i] for i in live.slots[topic]])
    for number, line in lines:
        if isinstance(line, BadInput):
            yield number, line
            continue
        if not line.strip():
            continue
        try:
            message = echo.row(line)
            frames = live.message(topic, message.time, message.values)
        except BadInput as error:
            yield number, BadInput(f"line {number}: {error}")
            continue
        for frame in frames:
            yield number, frame
    for frame in live.finish():
        yield 0, frame


class MessageFeed:
    """A ROS node's core, for any client library: message objects in (rospy's or rclpy's), recognised ticks out.
    A message that cannot be used is one line through ``warn`` (each topic's first, then at most one a
    second with the count since) and changes nothing; the node keeps running.

    ``receive`` recognises a message at once. A node whose callbacks must not wait ``offer``s them instead, from
    any thread: they wait in a queue of ``queue_size`` messages (the oldest dropped first when it is full, and
    counted in ``dropped``) until ``pending`` recognises them; ``drain`` recognises what is queued and decides every
    frame held, on shutdown. ``decode(topic, message)`` turns a queued message into a message object (a ROS 1
    node queues the raw bytes), or returns None for one already said to be unusable."""

    def __init__(self, model: Recognizer, warn: Callable[[str], None], clock: Callable[[], float],
                 max_hold: float | None = None, queue_size: int = QUEUE,
                 decode: Callable[[str, Any], Any] | None = None):
        self.live = LiveRecognizer(model, warn, max_hold)
        self.warn, self.clock = warn, clock  # clock: seconds, to pace the error lines
        self.errors: dict[str, tuple[float, int]] = {}  # topic -> (when its last error was said, errors since)
        self.frames = self.bad = 0
        self.queue_size, self.decode = queue_size, decode
        self.queue: collections.deque[tuple[str, Any, int]] = collections.deque()
        self.ready = threading.Condition()
        self.dropped = 0
        self._drops_said = (float("-inf"), 0)  # when dropped messages were last said, and how many by then

    @property
    def topics(self) -> list[str]:
        return self.live.topics

    @property
    def classes(self) -> list[str]:
        return self.live.model.classes

    def receive(self, topic: str, message: Any, received: int) -> list[LiveFrame]:
        """One message: its header stamp as its time, else ``received`` (ns)."""
        try:
            time = rostopic.message_time(message) or received
            frames = self.live.message(topic, time, rostopic.message_values(message, topic))
        except BadInput as error:
            self.error(topic, str(error))
            return []
        self.frames += len(frames)
        return frames

    def offer(self, topic: str, message: Any, received: int) -> None:
        """Queue a message for ``pending`` (any thread; never waits): the oldest is dropped when the queue is full."""
        with self.ready:
            if len(self.queue) >= self.queue_size:
                self.queue.popleft()
                self.dropped += 1
            self.queue.append((topic, message, received))
            self.ready.notify()

    def pending(self, timeout: float | None = None) -> list[LiveFrame]:
        """The messages queued so far recognised (waiting up to ``timeout`` s for one when none is)."""
        with self.ready:
            if not self.queue and timeout != 0:
                self.ready.wait(timeout)
            taken, self.queue = self.queue, collections.deque()
            dropped = self.dropped
        frames = []
        for topic, message, received in taken:
            if self.decode is not None:
                try:
                    message = self.decode(topic, message)
                except Exception as error:  # a buffer its type cannot read (genpy's, struct's errors): said, skipped
                    self.error(topic, f"a {topic} message cannot be read ({type(error).__name__}: {error})")
                    continue
                if message is None:
                    continue
            frames += self.receive(topic, message, received)
        self._say_drops(dropped)
        return frames

    def _say_drops(self, dropped: int) -> None:
        said_at, said = self._drops_said
        now = self.clock()
        if dropped > said and (not said or now - said_at >= DROPS_SAID_EVERY_S):
            self._drops_said = (now, dropped)
            self.warn(f"warning: the recogniser falls behind the feed: {dropped:,} message"
                      f"{'s' * (dropped != 1)} dropped so far, the oldest first (the queue holds {self.queue_size:,})")

    def drain(self) -> list[LiveFrame]:
        """On shutdown: every queued message recognised, then every frame held decided (``finish``)."""
        return self.pending(0) + self.finish()

    def error(self, topic: str, text: str) -> None:
        """Say an error about ``topic``'s messages, paced."""
        self.bad += 1
        now = self.clock()
        said, since = self.errors.get(topic, (float("-inf"), 0))
        if now - said < 1.0:
            self.errors[topic] = (said, since + 1)
            return
        more = f" ({since} more since)" if since else ""
        self.errors[topic] = (now, 0)
        self.warn(f"error: {text}{more}")

    def finish(self) -> list[LiveFrame]:
        frames = self.live.finish()
        self.frames += len(frames)
        return frames
