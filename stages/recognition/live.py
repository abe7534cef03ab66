"""A model trained on ROS topics, fed live messages: `LiveRecognizer` puts each topic's messages on the
model's clock as collect put the bags on it (stages/sources/rostopic.py's `HoldLast`) and runs the same
`Recognizer` as predict and stream on every tick. `mlnseq stream` (`rostopic echo -p` on stdin), the ROS 1
node (`mlnseq ros`) and a ROS 2 node (docs/ros.md) all call it.

The model remembers its topics and rate (its manifest's ``reading``, written by collect --env rosbag).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from mlnseq.catalog.errors import BadInput
from mlnseq.recognition.recognizer import Prediction, Recognizer
from mlnseq.sources import rostopic

RATE_PROBE = 20  # messages of the clock topic whose median period gives the feed's rate
RATE_FACTOR = 2.0  # a feed faster or slower than the model's clock by more than this is said once


@dataclass(frozen=True)
class LiveFrame:
    """One tick of the model's clock: its time (ns, the messages' clock) and its recognition."""

    time: int
    prediction: Prediction

    lag: int = 0  # frames the model waited before deciding this one

    def record(self, classes: list[str]) -> dict[str, Any]:
        """The frame as stream writes it: episode, frame, time (s), class, probabilities, lag."""
        p = self.prediction
        return {"episode": 0, "frame": p.frame, "time": self.time / 1e9, "class": p.name,
                "probabilities": dict(zip(classes, p.probabilities.tolist())), "lag": self.lag}

    def json(self, classes: list[str]) -> str:
        return json.dumps(self.record(classes))


def model_topics(model: Recognizer) -> tuple[list[str], float]:
    """The topics and rate the model's frames were read with; refuses a model not read from ROS bags."""
    reading = model.manifest.reading or {}
    if reading.get("env") != "rosbag" or not reading.get("topics") or not reading.get("rate"):
        raise BadInput(f"the model's frames were read with --env {reading.get('env') or '?'}, not from ROS bags, so it "
                       "knows no topics: feed it frames by feature name (JSON or CSV lines)")
    return list(reading["topics"]), float(reading["rate"])


class LiveRecognizer:
    """Messages in (topic, time in ns, feature values), recognised ticks out. Bad messages raise BadInput and
    change nothing; ``warn`` hears the notes (a feed's rate far from the model's, late messages) once."""

    def __init__(self, model: Recognizer, warn: Callable[[str], None]):
        self.model, self.warn = model, warn
        self.topics, self.rate = model_topics(model)
        self.slots = rostopic.features_by_topic(model.features, self.topics)
        self.clock = rostopic.HoldLast(self.slots, len(model.features), self.rate)
        self.probe: list[int] | None = []  # the clock topic's first message times, until its rate is known
        self.said: set[str] = set()
        self.times: dict[int, int] = {}  # tick time of each frame not decided yet (a lagged decoder: lag + 1)
        self.lag = model.lag if model.decoding.decoder.lagged else 0

    def message(self, topic: str, time: int, values: Mapping[str, float]) -> list[LiveFrame]:
        """The ticks this message closes, recognised; then its values are held."""
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
        ticks = self.clock.push(topic, time, vector)
        if topic == self.topics[0]:
            self._probe(time)
        if topic in self.clock.late and topic not in self.said:
            self.said.add(topic)
            self.warn(f"note: a {topic} message arrived after a later tick was answered; it counts from the next tick")
        return self._recognise(ticks)

    def finish(self) -> list[LiveFrame]:
        """The ticks up to the last message, once the feed has ended, and a lagged decoder's pending frames."""
        return self._recognise(self.clock.finish()) + self._decided(self.model.finish())

    def _recognise(self, ticks: Iterable[tuple[int, np.ndarray]]) -> list[LiveFrame]:
        """Each tick stepped; the frames it decides (itself, or with a lag L the frame L ticks back) answered."""
        out = []
        for time, row in ticks:
            self.times[self.model.next_frame] = time
            out += self._decided(self.model.step(row).final)
        return out

    def _decided(self, predictions: Iterable[Prediction]) -> list[LiveFrame]:
        return [LiveFrame(self.times.pop(p.frame), p, self.lag) for p in predictions]

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
    second with the count since) and changes nothing; the node keeps running."""

    def __init__(self, model: Recognizer, warn: Callable[[str], None], clock: Callable[[], float]):
        self.live = LiveRecognizer(model, warn)
        self.warn, self.clock = warn, clock  # clock: seconds, to pace the error lines
        self.errors: dict[str, tuple[float, int]] = {}  # topic -> (when its last error was said, errors since)
        self.frames = self.bad = 0

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
