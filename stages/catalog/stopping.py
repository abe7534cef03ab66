"""SIGINT and SIGTERM heard by a live command (stream): it stops reading, decides and writes every frame it holds,
then exits with the signal's usual code (128 + its number: 130 for SIGINT, 143 for SIGTERM).

A signal that comes while the command waits for input ends the wait at once (`Stopped` is raised from the read);
one that comes while it answers frames takes effect at its next read, so every frame already read is answered
first. A second signal stops the process at once, as the signal does by default.
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM)


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
