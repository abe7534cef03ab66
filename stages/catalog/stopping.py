"""SIGINT and SIGTERM heard by a live command. ``stop_on_signals``: the nodes and servers (ros, echo, review) run
until a signal sets an event, then stop, and the handlers they replaced are put back. ``StopSignals``: stream stops
reading, decides and writes every frame it holds, then exits with the signal's usual code (128 + its number: 130
for SIGINT, 143 for SIGTERM).

With ``StopSignals`` a signal that comes while the command waits for input ends the wait at once (`Stopped` is
raised from the read); one that comes while it answers frames takes effect at its next read, so every frame already
read is answered first. A second signal stops the process at once, as the signal does by default.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator
from dataclasses import dataclass

SIGNALS = (signal.SIGINT, signal.SIGTERM)


@dataclass
class Heard:
    """What ``stop_on_signals`` hears: ``stop`` is set by SIGINT or SIGTERM (or by the caller), ``signal`` names the
    first signal heard; ``listening`` is False outside the main thread, where no handler can be set."""

    stop: threading.Event
    listening: bool = True
    signal: str | None = None


@contextlib.contextmanager
def stop_on_signals(stop: threading.Event | None = None) -> Iterator[Heard]:
    """An event SIGINT and SIGTERM set (``stop``, or a new one) while inside; the previous handlers after. Outside
    the main thread, where no handler can be set, only the caller sets it."""
    heard = Heard(stop or threading.Event())

    def set_stop(signum: int, frame) -> None:
        heard.signal = heard.signal or signal.Signals(signum).name
        heard.stop.set()

    try:
        previous = {signum: signal.signal(signum, set_stop) for signum in SIGNALS}
    except ValueError:  # not the main thread
        previous, heard.listening = {}, False
    try:
        yield heard
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


class Stopped(Exception):
    """A live command was asked to stop by a signal, and has answered what it read."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return 128 + self.signum

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


class StopSignals:
    """The signals a live command hears: ``installed()`` around the command, ``reading()`` around each read that
    may wait for input."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self.waiting = False

    def _heard(self, signum: int, frame) -> None:
        if self.signum is not None:  # a second signal: stop now, as by default
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        self.signum = signum
        if self.waiting:
            raise Stopped(signum)

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopSignals]:
        """Hear SIGINT and SIGTERM in this block (outside the main thread, signals stay the caller's)."""
        try:
            previous = {signum: signal.signal(signum, self._heard) for signum in SIGNALS}
        except ValueError:  # not the main thread
            yield self
            return
        try:
            yield self
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)

    @contextlib.contextmanager
    def reading(self) -> Iterator[None]:
        """A read that may wait: a signal heard before it, or during it, raises `Stopped`."""
        self.waiting = True
        try:
            if self.signum is not None:
                raise Stopped(self.signum)
            yield
        finally:
            self.waiting = False
