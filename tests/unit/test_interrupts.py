"""The signal guard of a run: a signal becomes an exception in the main thread, never inside a
held section, and the handlers the caller had are given back (in this process, no run)."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import textwrap

import pytest
from redline.agent.interrupts import Terminated, signals_as_exceptions


@pytest.fixture(autouse=True)
def hangup_by_default():
    """SIGHUP as a terminal leaves it: a suite started under nohup inherits it ignored, which
    the guard rightly keeps (`test_an_ignored_signal_stays_ignored`)."""
    before = signal.signal(signal.SIGHUP, signal.SIG_DFL)
    yield
    signal.signal(signal.SIGHUP, before)


def test_the_guard_raises_in_the_main_thread_and_restores_the_handlers() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Terminated) as caught, signals_as_exceptions():
        signal.raise_signal(signal.SIGTERM)  # delivered to this thread before it returns
        pytest.fail("the signal did not interrupt")
    assert caught.value.signal_name == "SIGTERM"
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_signal_in_a_held_section_is_raised_when_the_section_ends() -> None:
    finished = []
    with pytest.raises(Terminated), signals_as_exceptions() as guard:
        with guard.held():
            signal.raise_signal(signal.SIGHUP)
            finished.append("held section")
        finished.append("after it")
    assert finished == ["held section"]


def test_a_signal_while_stopping_is_raised_once_everything_is_stopped() -> None:
    finished = []
    with pytest.raises(KeyboardInterrupt), signals_as_exceptions() as guard:
        guard.stopping()
        signal.raise_signal(signal.SIGINT)
        finished.append("shut down")
    assert finished == ["shut down"]


def test_a_callers_own_handler_runs_but_never_inside_a_held_section() -> None:
    caught: list[int] = []

    def own(signum: int, _frame: object) -> None:
        caught.append(signum)

    previous = signal.signal(signal.SIGTERM, own)
    try:
        with signals_as_exceptions() as guard:
            signal.raise_signal(signal.SIGTERM)
            assert caught == [signal.SIGTERM]  # at once, and the run goes on
            with guard.held():
                signal.raise_signal(signal.SIGTERM)
                assert caught == [signal.SIGTERM]
            assert caught == [signal.SIGTERM] * 2
        assert signal.getsignal(signal.SIGTERM) is own
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_an_ignored_signal_stays_ignored() -> None:
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with signals_as_exceptions():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            signal.raise_signal(signal.SIGHUP)
    finally:
        signal.signal(signal.SIGHUP, previous)


def test_a_signal_whose_exception_was_swallowed_is_raised_again_when_the_work_ends() -> None:
    """Seen under load in CI: a Ctrl-C landed inside a zenoh put, which printed "Exception
    ignored" and went on; the run finished as if nothing had happened."""
    finished = []
    with pytest.raises(KeyboardInterrupt), signals_as_exceptions() as guard:
        with contextlib.suppress(KeyboardInterrupt):  # as a native callback swallows it
            signal.raise_signal(signal.SIGINT)
        finished.append("the work went on")
        guard.raise_swallowed()
        finished.append("after the work")
    assert finished == ["the work went on"]


def test_nothing_is_raised_again_when_no_signal_came() -> None:
    with signals_as_exceptions() as guard:
        guard.raise_swallowed()


def test_a_stop_signal_sets_its_event_even_when_it_comes_while_the_event_is_waited_on() -> None:
    # the signal lands while the main thread holds the event's own lock, as inside
    # ``stop.wait()``: a handler calling ``stop.set()`` there waited for that lock for ever
    # (a monitor that never stopped on SIGTERM); in a process of its own, so such a hang fails
    # the test by its timeout instead of stopping the suite
    script = textwrap.dedent(
        """
        import os, signal, threading
        from redline.agent.interrupts import set_on_signals
        stop = threading.Event()
        set_on_signals(stop, signal.SIGUSR1)
        with stop._cond:
            os.kill(os.getpid(), signal.SIGUSR1)
            for _ in range(1000):  # the handler runs between two of these steps
                pass
        print("stopped" if stop.wait(10) else "not set")
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=30, check=False
    )
    assert (done.returncode, done.stdout.strip()) == (0, "stopped"), done.stderr
