"""stream: recognise live frames, one per input line, answering each at once.

Input: JSON lines (an object of feature name -> value per frame) or CSV (a header line, then one row per
frame); a line that starts with ``{`` before any CSV row makes the stream JSON (a log banner before it is
no CSV header, and is said as a line that is not JSON); a CSV header naming none of the model's features (a CSV
without one) is said in a note. An ``episode`` key or column starts a new episode whenever its value changes.
Output: one JSON object per frame, written and flushed before the stream waits for more input: ``{"episode",
"frame", "class", "probabilities": {class: p}, "lag"}`` (and ``"time"``, the input's ``time`` or ``timestamp`` of
that frame, and ``"stamp"``, when it has them; ``"why"`` with ``explain``). ``decode`` decodes with another decoder
than the model's, as predict's --decode. A model with a lag of L frames
answers frame t once frame t + L has arrived, and the episode's last L frames at its end (the next episode, or the
end of the input); the frames that arrived together (a backlog, a file) are decided together, the same classes
faster. Everything is causal and stateful (the previous frame for the change predicates, the network's state,
the decoder's belief and its last L frames).

A bad line (not JSON, not UTF-8, a missing feature, NaN, inf or a non-number) is reported on stderr with
its line number and skipped; with ``strict`` it stops the stream (exit 2). Keys the model does not use (a
timestamp, say) are ignored, and said once. Input is read in chunks, and a line longer than
``max_line_bytes`` is never held: it is counted to its end, reported with its length and skipped (with
``strict``, the stream stops as soon as the line passes the limit).

`rostopic echo -p TOPIC` (a CSV whose header starts with ``%time``) is read as the model's topic and put on its
clock as collect put the bags on it (stages/recognition/live.py); each answer then carries the frame's ``time``
(seconds from the first message) and ``stamp`` (the messages' clock), and ``why`` with ``explain``.
"""

from __future__ import annotations

import contextlib
import csv
import itertools
import json
import math
from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, ContextManager

from mlnseq.catalog.decoders import parse_decoding
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.stopping import Stopped, StopSignals
from mlnseq.recognition import live as ros_live
from mlnseq.recognition.live import encoded
from mlnseq.recognition.recognizer import Recognizer
from mlnseq.recognition import rostopic

EPISODE = "episode"
TIMES = ("time", "timestamp")  # an input key naming a frame's time, echoed on its output line as "time"
STAMP = "stamp"  # an input key naming a frame's time on the messages' clock (predict's column), echoed as it came
MAX_LINE_BYTES = 1024 * 1024  # a JSON frame of ~20,000 features; DESK's is 80 bytes
CHUNK_BYTES = 64 * 1024  # read at most this much at once; a chunk holds many frames, or part of one


@dataclass(frozen=True)
class StreamOptions:
    """Options of `mlnseq stream`."""

    model: Path
    strict: bool = False
    max_line_bytes: int = MAX_LINE_BYTES
    max_hold: float | None = None  # `rostopic echo -p`: seconds a tick holds the feed's last row; default: the model's
    explain: int = 0  # N > 0: each line carries "why", its frame's N largest terms (docs/explain.md)
    decode: str | None = None  # a decoder, as predict's --decode; default: the model's
    monitor: bool = False  # an alert line the moment a recording turns suspect (the model's audit profile)

    def validate(self) -> None:
        if self.explain < 0:
            raise BadInput(f"--explain {self.explain}: give how many terms each line shows (0: none)")
        if self.decode is not None:
            parse_decoding(self.decode)
        if self.max_line_bytes < 1:
            raise BadInput(f"--max-line-bytes {self.max_line_bytes}: a line limit is at least 1 byte")
        if self.max_hold is not None and not self.max_hold > 0:
            raise BadInput(f"--max-hold must be above 0 seconds (inf: no bound), got {self.max_hold:g}")


@dataclass
class StreamSummary:
    """What a stream did: frames answered, lines skipped, episodes seen."""

    frames: int = 0
    skipped: int = 0
    episodes: int = 0


class InputLine(BadInput):
    """One input line that cannot be a frame; names the line."""


def lines_of(source: BinaryIO, limit: int, stop_early: bool = False,
             before_wait: Sequence[Callable[[], None]] = (),
             reading: Callable[[], ContextManager[Any]] = contextlib.nullcontext) -> Iterator[str | InputLine]:
    """Every line of ``source`` without its newline, decoded as UTF-8, read in chunks of at most CHUNK_BYTES
    as they arrive; each of ``before_wait`` is called before each read, which may wait for input, and the read
    runs in ``reading()`` (where a stop signal ends it). A line over ``limit`` bytes is never held: it is an
    InputLine naming its number and length once its end is read, or (``stop_early``) as soon as it passes the
    limit."""
    read = getattr(source, "read1", source.read)  # read1: what is there, without waiting to fill the chunk
    number, held, size = 1, [], 0  # the line being read: its number, its pieces (within the limit), its length
    for chunk in _chunks(read, before_wait, reading):
        *ends, rest = chunk.split(b"\n")
        for piece in ends:
            if stop_early and size + len(piece) > limit >= size:
                yield InputLine(f"line {number}: over --max-line-bytes {limit:,} bytes (raise it to read such lines)")
            yield _line(number, b"".join([*held, piece]) if held else piece, size + len(piece), limit)
            number, held, size = number + 1, [], 0
        if size + len(rest) > limit:
            if stop_early and size <= limit:
                yield InputLine(f"line {number}: over --max-line-bytes {limit:,} bytes (raise it to read such "
                                "lines)")
            held = []
        elif rest:
            held.append(rest)
        size += len(rest)
    if size:
        yield _line(number, b"".join(held), size, limit)


def _chunks(read: Callable[[int], bytes], before_wait: Sequence[Callable[[], None]],
            reading: Callable[[], ContextManager[Any]]) -> Iterator[bytes]:
    """What ``read`` gives, a chunk at a time, until the end of the input; ``before_wait`` called before each read."""
    while True:
        for then in before_wait:
            then()
        with reading():
            chunk = read(CHUNK_BYTES)
        if not chunk:
            return
        yield chunk


def _line(number: int, data: bytes, size: int, limit: int) -> str | InputLine:
    if size > limit:
        return InputLine(f"line {number}: {size:,} bytes, over --max-line-bytes {limit:,} (raise it to read such "
                         "lines); skipped")
    try:
        return data.decode().removesuffix("\r")
    except UnicodeDecodeError as error:
        return InputLine(f"line {number}: not UTF-8 text ({error})")


def frames_of(lines: Iterable[str | InputLine], features: Collection[str] = (),
              note: Callable[[str], None] | None = None) -> Iterator[tuple[int, dict[str, Any] | InputLine]]:
    """(line number, the frame as a mapping, or the error that line makes) for every non-blank line. A line of text
    before the first JSON frame (a log banner) is not JSON: an error, skipped. A CSV header naming none of
    ``features`` (a headerless CSV's first row) is said through ``note`` at the first row."""
    header: list[str] | None = None
    json_lines: bool | None = None
    header_at = 0  # the header's line number
    for number, line in enumerate(lines, start=1):
        if isinstance(line, InputLine):
            yield number, line
            continue
        if not line.strip():
            continue
        if json_lines is None and line.lstrip().startswith("{"):
            json_lines = True  # the first JSON frame decides: the text before it was no CSV header
            if header is not None:
                yield header_at, InputLine(f"line {header_at}: not JSON (text before the first JSON frame); skipped")
        if json_lines is None and header is None:
            header, header_at = _csv_row(line, number), number
            if isinstance(header, InputLine):
                yield number, header
                header = None
            continue
        if json_lines:
            try:
                frame = _json(line)
            except (ValueError, RecursionError) as error:
                what = "nested too deep" if isinstance(error, RecursionError) else str(error)
                yield number, InputLine(f"line {number}: not JSON ({what})")
                continue
            if not isinstance(frame, dict):
                yield number, InputLine(f"line {number}: expected a JSON object of feature -> value")
                continue
            yield number, frame
            continue
        row = _csv_row(line, number)
        if isinstance(row, InputLine):
            yield number, row
            continue
        if json_lines is None and features and note is not None and not set(header) & set(features):
            note(f"note: line {header_at} was read as the CSV header ({_some(header)}) and names none of the model's "
                 f"features: a CSV stream starts with a header line of feature names ({_some(list(features))})")
        json_lines = False  # a CSV row: the stream is CSV
        if len(row) != len(header):
            yield number, InputLine(f"line {number}: {len(row)} fields, the header has {len(header)}")
            continue
        yield number, {name: _number(value) if name != EPISODE else value for name, value in zip(header, row)}


def _some(names: list[str]) -> str:
    return ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")


def _json(line: str) -> Any:
    """A JSON line; an integer too long for a float is read as one (infinite, so refused as a value)."""
    return json.loads(line, parse_int=lambda digits: int(digits) if len(digits) < 300 else float(digits))


def _csv_row(line: str, number: int) -> list[str] | InputLine:
    try:
        return next(csv.reader([line]))
    except csv.Error as error:  # a field over the csv module's limit, say
        return InputLine(f"line {number}: not a CSV row ({error})")


def _check_episode(frame: dict[str, Any], number: int) -> None:
    """An episode id must be echoed back as JSON: NaN or infinity is not an id."""
    value = frame.get(EPISODE)
    if isinstance(value, float) and not math.isfinite(value):
        raise InputLine(f"line {number}: episode {value} is not an id (NaN or infinite)")


def _number(text: str) -> float | str:
    try:
        return float(text)
    except ValueError:
        return text  # the recogniser names the feature that is not a number


def answer_line(model: Recognizer, prediction: Any, episode: Any, when: dict[str, Any] | None) -> dict[str, Any]:
    """A decided frame's output: its episode, frame (and input time and stamp), class, probabilities and the model's
    lag."""
    line = {EPISODE: 0 if episode is None else episode, "frame": prediction.frame, **(when or {}),
            "class": prediction.name, "probabilities": dict(zip(model.classes, prediction.probabilities.tolist())),
            "lag": model.lag if model.decoding.decoder.lagged else 0}
    if prediction.why is not None:
        line["why"] = prediction.why
    return line


def _step(model: Recognizer, frame: dict[str, Any], number: int, times: dict[int, Any]) -> Any:
    """One frame through the model, its input time kept until its frame is answered; a bad frame names its line.
    A lagged decoder's decisions wait for ``model.decide()``."""
    time = next((frame[key] for key in TIMES if key in frame), None)
    when = {"time": time} if time is not None else {}
    if STAMP in frame:
        when[STAMP] = frame[STAMP]
    if when:
        times[model.next_frame] = when
    try:
        return model.step(frame, decide=False)
    except BadInput as error:
        raise InputLine(f"line {number}: {error}") from None


def run(options: StreamOptions, source: BinaryIO, emit: Callable[[str], None],
        warn: Callable[[str], None]) -> StreamSummary:
    """Answer every frame of ``source`` (bytes, one frame a line) with one JSON line through ``emit``; report
    bad lines through ``warn``. SIGINT or SIGTERM: the frames read are answered, then `Stopped` is raised."""
    options.validate()
    model = ros_live.prepared(options.model, warn, options.decode, options.explain)
    if options.monitor:
        from mlnseq.auditing.monitor import monitored

        model = monitored(model, options.model)
    notes = model.manifest.notes  # said in full by export, which made them, and shown by info; here one line
    if len(notes) == 1:
        warn(f"note: {notes[0]}")
    elif notes:
        warn(f"note: the model holds {len(notes)} notes from its export (`mlnseq info {options.model}` shows them)")
    with StopSignals().installed() as stop:
        before_wait: list[Callable[[], None]] = []  # _serve adds its answer to the frames it held back
        lines = lines_of(source, options.max_line_bytes, options.strict, before_wait, stop.reading)
        head = []  # the blank lines before the first, and the first (a `rostopic echo -p` header?)
        for line in lines:
            head.append(line)
            if not isinstance(line, str) or line.strip():
                break
        if head and isinstance(head[-1], str) and rostopic.is_header(head[-1]):
            return _echo(options, model, head[-1], enumerate(lines, start=len(head) + 1), emit, warn)
        return _serve(options, model, itertools.chain(head, lines), emit, warn, before_wait)


def _serve(options: StreamOptions, model: Recognizer, lines: Iterable[str | InputLine], emit: Callable[[str], None],
           warn: Callable[[str], None], before_wait: list[Callable[[], None]]) -> StreamSummary:
    """JSON or CSV frames: frame t answered once frame t + lag has arrived, the pending ones at an episode's end.
    The frames read together are stepped first and decided together, before the next read (``before_wait``)."""
    used = set(model.features) | {EPISODE, *TIMES, STAMP}
    ignored: set[str] = set()
    summary = StreamSummary()
    episode: Any = None
    times: dict[int, Any] = {}  # the input time of each frame not answered yet (at most lag + 1)

    def answer(predictions: Iterable[Any], episode: Any, ended: bool = False) -> None:
        where = None
        for prediction in predictions:
            when = times.pop(prediction.frame, None)
            emit(encoded(answer_line(model, prediction, episode, when)))
            summary.frames += 1
            where = {"frame": prediction.frame, **(when or {})}
        if where is not None or ended:  # --monitor: the alerts raised since, after the frames answered with them
            alert(model, emit, {EPISODE: 0 if episode is None else episode, **(where or {})})

    with answering_held(before_wait, lambda: answer(model.decide(), episode)):
        try:
            for number, frame in frames_of(lines, model.features, warn):
                try:
                    if isinstance(frame, InputLine):
                        raise frame
                    _check_episode(frame, number)
                    unused = set(frame) - used - ignored
                    if unused:
                        ignored |= unused
                        warn(f"note: line {number}: keys the model does not use are ignored: "
                             f"{', '.join(sorted(unused))}")
                    if not summary.episodes or frame.get(EPISODE) != episode:
                        if summary.episodes:
                            answer(model.finish(), episode, ended=True)  # its pending frames, decided at once
                            times.clear()
                            model.reset()
                        episode = frame.get(EPISODE)
                        summary.episodes += 1
                    prediction = _step(model, frame, number, times)
                except InputLine as error:
                    summary.skipped += 1
                    if options.strict:
                        raise
                    warn(f"error: {error}")
                    continue
                answer(prediction.final, episode)
        except Stopped:  # SIGINT or SIGTERM: every frame read is decided and answered, then the signal's exit
            answer(model.finish(), episode, ended=True)
            raise
        answer(model.finish(), episode, ended=True)  # the end of the input: the pending frames, decided at once
    return summary


def alert(model: Any, emit: Callable[[str], None], where: dict[str, Any]) -> None:
    """A monitored model's alerts (`--monitor`), each a JSON line after the frames answered with it."""
    if hasattr(model, "alerts"):
        from mlnseq.auditing.monitor import alert_line

        for raised in model.alerts():
            emit(alert_line(raised, model.profile, where))


@contextlib.contextmanager
def answering_held(before_wait: list[Callable[[], None]], answer_held: Callable[[], None]) -> Iterator[None]:
    """In this block, the decisions held back are answered before each read that may wait (``before_wait``)."""
    before_wait.append(answer_held)
    try:
        yield
    finally:
        before_wait.remove(answer_held)


def _echo(options: StreamOptions, model: Recognizer, header: str, lines: Iterable[tuple[int, str | InputLine]],
          emit: Callable[[str], None], warn: Callable[[str], None]) -> StreamSummary:
    """A `rostopic echo -p` feed: its rows on the model's clock, one answer per tick with its time."""
    live = ros_live.LiveRecognizer(model, warn, options.max_hold)
    topic = ros_live.echo_topic(live)
    summary = StreamSummary(episodes=1)
    try:
        for _, answer in ros_live.feed_echo(live, topic, lines, header):
            if isinstance(answer, BadInput):
                summary.skipped += 1
                if options.strict:
                    raise InputLine(str(answer))
                warn(f"error: {answer}")
            else:
                emit(answer.json(model.classes))
                summary.frames += 1
                alert(model, emit, {EPISODE: answer.episode, "frame": answer.prediction.frame,
                                    "time": (answer.time - answer.start) / 1e9, STAMP: answer.time / 1e9})
    except Stopped:  # SIGINT or SIGTERM: the ticks up to the last message read, and the frames held, answered
        for frame in live.finish():
            emit(frame.json(model.classes))
        raise
    summary.episodes = live.episode + 1  # time that jumped back started the others
    return summary
