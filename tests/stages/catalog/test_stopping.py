"""The one stop-on-signal helper of the live commands (ros, echo, review's server): a real SIGINT or SIGTERM sent to
this process sets the event and is named, and the handlers it replaced are back afterwards."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from mlnseq.catalog.stopping import stop_on_signals


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_sets_the_stop_and_the_handlers_come_back(signum):
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with stop_on_signals() as heard:
        assert heard.listening and not heard.stop.is_set()
        os.kill(os.getpid(), signum)
        assert heard.stop.wait(5)
        os.kill(os.getpid(), signal.SIGINT if signum == signal.SIGTERM else signal.SIGTERM)  # a second: the first kept
    assert heard.signal == signal.Signals(signum).name
    assert {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)} == before


def test_the_callers_event_is_the_one_set_and_outside_the_main_thread_nothing_is_installed():
    stop, found = threading.Event(), []
    with stop_on_signals(stop) as heard:
        assert heard.stop is stop

    def outside() -> None:
        with stop_on_signals() as elsewhere:
            found.append(elsewhere)

    worker = threading.Thread(target=outside)
    worker.start()
    worker.join()
    assert not found[0].listening and found[0].signal is None
