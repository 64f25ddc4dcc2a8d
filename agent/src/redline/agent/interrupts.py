"""The signals that end a run, turned into exceptions in the main thread so that it cleans up.

Every process of a run is started in its own session (a Ctrl-C in the terminal must not reach
the component half-way), so the runner alone learns that the run must end, and it must then stop
every process and finish the recording. Python turns SIGINT into `KeyboardInterrupt` by itself,
but SIGTERM (what CI sends on cancel) and SIGHUP (a closed terminal) would kill the runner on the
spot and leave the component, the recorder and the monitor running. While a run is in progress,
`signals_as_exceptions` makes them raise `Terminated` in the main thread instead.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType, TracebackType
from typing import Any

HANDLED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: What a run's recording says when it was stopped by a signal (else "ok" or "failed").
INTERRUPTED, TERMINATED = "interrupted", "terminated"


class Terminated(BaseException):
    """Raised in the main thread by SIGTERM or SIGHUP while a run is in progress.

    A BaseException, as `KeyboardInterrupt` is, so that ``except Exception`` in a test or a
    caller does not swallow it.
    """

    def __init__(self, signum: int) -> None:
        self.signum = signum
        self.signal_name = signal.Signals(signum).name
        super().__init__(f"terminated by {self.signal_name}")


def signal_exception(signum: int) -> BaseException:
    """What the signal raises: `KeyboardInterrupt` for SIGINT, as Python's own handler does."""
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


def ending(exc: BaseException) -> dict[str, str]:
    """The run metadata that says how a run ended with ``exc``: status, signal and error."""
    if isinstance(exc, KeyboardInterrupt):
        return {"status": INTERRUPTED, "signal": "SIGINT", "error": "interrupted by SIGINT"}
    if isinstance(exc, Terminated):
        return {"status": TERMINATED, "signal": exc.signal_name, "error": str(exc)}
    return {"status": "failed", "error": f"{type(exc).__name__}: {exc}"[:4000]}


def set_on_signals(event: threading.Event, *signums: int) -> None:
    """Set ``event`` when one of the signals comes (in the main thread, which installs it).

    Not by calling ``event.set()`` in the handler: a handler runs in the main thread between two
    of its steps, and when those are inside ``event.wait()`` holding the event's own lock,
    ``set()`` waits for that lock for ever (seen: a monitor that never stopped on SIGTERM, its
    main thread blocked in the handler). A thread of its own sets it instead, as soon as the
    main thread lets go of the lock."""

    def handler(_signum: int, _frame: FrameType | None) -> None:
        threading.Thread(target=event.set, name="signal-stop", daemon=True).start()

    for signum in signums:
        signal.signal(signum, handler)


def _is_default(signum: int, handler: Any) -> bool:
    return handler is signal.SIG_DFL or (
        signum == signal.SIGINT and handler is signal.default_int_handler
    )


class SignalGuard:
    """While entered in the main thread, SIGTERM and SIGHUP raise `Terminated` and SIGINT raises
    `KeyboardInterrupt` there, where their handler was Python's default; a caller's own handler
    (the agent daemon finishes its job on the first SIGTERM and releases it on the second) still
    runs. An ignored signal (nohup's SIGHUP) stays ignored. The previous handlers come back on
    exit.

    No signal cuts a process start or the shutdown in half: inside `held()`, after `stopping()`
    and after one signal has been raised, a signal is noted, not acted on. A noted signal is
    acted on when the held section ends, or when the guard exits (once everything is stopped):
    a caller's handler is called then in any case (it must learn of the signal), a default one
    raises unless an exception is already on its way. Entering again while entered
    (`run_executions` around `run_suite`) shares the handlers; each exit ends that run's
    stopping.
    """

    def __init__(self) -> None:
        self._previous: dict[int, Any] = {}
        self._depth = 0
        self._held = 0
        self._stopping = False
        self.pending: list[int] = []
        #: the signal last raised as an exception, until the guard exits
        self._raised: int | None = None

    def __enter__(self) -> SignalGuard:
        if self._depth == 0 and threading.current_thread() is threading.main_thread():
            for signum in HANDLED:
                handler = signal.getsignal(signum)
                if _is_default(signum, handler) or callable(handler):
                    self._previous[signum] = handler
                    signal.signal(signum, self._handle)
        self._depth += 1
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._depth -= 1
        pending, self.pending, self._stopping = self.pending, [], False
        previous = dict(self._previous)
        if self._depth == 0:
            for signum, handler in self._previous.items():
                signal.signal(signum, handler)
            self._previous.clear()
            self._raised = None
        own = [signum for signum in pending if _is_default(signum, previous.get(signum))]
        for signum in dict.fromkeys(s for s in pending if s not in own):
            previous[signum](signum, None)
        if own and kind is None:
            raise signal_exception(own[0])

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self._held or self._stopping:
            self.pending.append(signum)
            return
        self._act(signum, frame)

    def _act(self, signum: int, frame: FrameType | None) -> None:
        handler = self._previous.get(signum)
        if _is_default(signum, handler):
            self._stopping = True
            self._raised = signum
            raise signal_exception(signum)
        assert callable(handler), handler  # installed only over a default or callable one
        try:
            handler(signum, frame)  # a caller's own: it may let the run go on
        except BaseException:
            self._stopping = True
            raise

    def raise_swallowed(self) -> None:
        """Raise again a signal whose exception never arrived: raised inside a native callback
        (a zenoh put), it is printed as "Exception ignored" and the code goes on. Called where
        the work it would have cut short has ended normally, so the run still ends as the signal
        asked (seen under load: a Ctrl-C lost, the run reported as ok)."""
        if self._raised is not None:
            raise signal_exception(self._raised)

    def stopping(self) -> None:
        """The run is shutting down: from now on signals are noted, not acted on."""
        self._stopping = True

    @contextmanager
    def held(self) -> Iterator[None]:
        """A section no signal may cut in half (a process started and not yet known, one of
        Redline's own messages put). Signals interrupt only the main thread: elsewhere there is
        nothing to hold."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        self._held += 1
        try:
            yield
        finally:
            self._held -= 1
        while not self._held and not self._stopping and self.pending:
            self._act(self.pending.pop(0), None)


_MAIN = SignalGuard()


def signals_as_exceptions() -> SignalGuard:
    """The guard of a run (see `SignalGuard`). Signals reach Python in the main thread only:
    called from another thread it installs nothing, and a signal keeps its usual effect."""
    return _MAIN if threading.current_thread() is threading.main_thread() else SignalGuard()
