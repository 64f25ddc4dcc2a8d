"""What an action sees while it runs: the parameter set, the zenoh link, the stop signal."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Mapping
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field, replace
from typing import Any

import zenoh
from redline.recording.format import DRIVER_PREFIX, RECORDER_SENT_KEY
from redline.testing.metrics import Tally
from redline.testing.signals import Stop

SPIN_NS = 1_000_000  # sleep to ~1 ms before a deadline, then spin: plain sleep drifts (FIELD-NOTES)


Listener = Callable[[zenoh.Sample], None]


class Link:
    """The test driver's zenoh session with one declared publisher per key, shared by actions.

    Thread-safe, so actions running in parallel can share it. Publishers never use
    ``CongestionControl.BLOCK``: the load generator must not be throttled by a slow subscriber.
    """

    def __init__(
        self, session: zenoh.Session, hold: Callable[[], AbstractContextManager[Any]] = nullcontext
    ) -> None:
        """``hold``: a section no signal may cut (the runner's `SignalGuard.held`), around each
        of Redline's own messages, which a put cut half-way would leave empty in the recording."""
        self.session = session
        self._hold = hold
        self._publishers: dict[tuple[str, str | None], zenoh.Publisher] = {}
        self._lock = threading.Lock()
        self._sequences: dict[str, int] = {}
        self._subscribers: dict[str, zenoh.Subscriber[None]] = {}
        self._listeners: dict[str, dict[int, Listener]] = {}
        self._sent: dict[str, int] = {}

    def publisher(self, key: str, encoding: str | None = None) -> zenoh.Publisher:
        """The publisher for ``key`` (declared on first use, then cached)."""
        ident = (key, encoding)
        with self._lock:
            found = self._publishers.get(ident)
            if found is None:
                found = self.session.declare_publisher(
                    key,
                    encoding=encoding,
                    congestion_control=zenoh.CongestionControl.DROP,
                )
                self._publishers[ident] = found
            return found

    def next_sequence(self, key: str) -> int:
        """The next sequence number of ``key`` (0, 1, 2, ... per key for the whole run)."""
        with self._lock:
            number = self._sequences.get(key, 0)
            self._sequences[key] = number + 1
            return number

    def listen(self, key: str, listener: Listener) -> Callable[[], None]:
        """Call ``listener`` with every sample on ``key`` until the returned function is called.

        One subscriber per key expression is declared on first use and kept for the run, so
        actions that wait for samples again and again do not declare a subscriber each time.
        """
        with self._lock:
            listeners = self._listeners.setdefault(key, {})
            listeners[id(listener)] = listener
            if key not in self._subscribers:
                self._subscribers[key] = self.session.declare_subscriber(
                    key, lambda sample: self._dispatch(key, sample)
                )

        def forget() -> None:
            with self._lock:
                listeners.pop(id(listener), None)

        return forget

    def _dispatch(self, key: str, sample: zenoh.Sample) -> None:
        for listener in list(self._listeners.get(key, {}).values()):
            listener(sample)

    def put_json(self, key: str, obj: dict[str, Any]) -> None:
        """Publish a JSON object (Redline's own messages: driver metrics)."""
        payload = json.dumps(obj, default=str)
        with self._hold():
            self.publisher(key, "application/json").put(payload)

    def count_sent(self, key: str, samples: int = 1) -> None:
        """Count samples `Publish` put on ``key`` (loops count in bulk when they finish)."""
        with self._lock:
            self._sent[key] = self._sent.get(key, 0) + samples

    def published_keys(self) -> set[str]:
        """Every key this link declared a publisher for (`Publish`, `Replay`, custom actions)."""
        with self._lock:
            return {key for key, _encoding in self._publishers}

    def sent(self) -> dict[str, int]:
        """Samples put per key through `Publish` on this link so far."""
        with self._lock:
            return dict(self._sent)

    def _report_sent(self) -> None:
        """Tell the run's recorder how many samples were put per key, so that it can count what
        zenoh dropped on the way (DROP congestion control) in the recording. Without a recorder
        (a unit test, a REPL) the query finds no queryable and returns at once."""
        sent = self.sent()
        if not sent:
            return
        try:
            for _ in self.session.get(RECORDER_SENT_KEY, payload=json.dumps(sent), timeout=5.0):
                pass
        except zenoh.ZError:
            pass  # the session is already closed: nothing to tell
        with self._lock:
            self._sent.clear()

    def close(self) -> None:
        """Report the put counts to the recorder; undeclare every publisher and subscriber (the
        session itself belongs to the caller)."""
        self._report_sent()
        with self._lock:
            for publisher in self._publishers.values():
                publisher.undeclare()
            self._publishers.clear()
            for subscriber in self._subscribers.values():
                subscriber.undeclare()
            self._subscribers.clear()
            self._listeners.clear()


@dataclass
class Context:
    """The state an action runs in.

    ``params`` is the current parameter set; ``link`` the zenoh link (``None`` when actions run
    outside a test run, e.g. in a unit test); ``stop`` is set when the run must end early (Ctrl-C,
    a component that died, or a parent action's time limit), and long-running actions watch it.
    """

    params: Mapping[str, Any]
    case: str = "adhoc"  # actions run outside a test case (unit tests, a REPL) report under these
    phase: str = "adhoc"
    link: Link | None = None
    stop: threading.Event = field(default_factory=Stop)
    reports: list[dict[str, Any]] = field(default_factory=list)
    tallies: dict[tuple[str, str], Tally] = field(default_factory=dict)
    #: each action of the phase's tree (by id) with its path (`redline.testing.paths`)
    paths: Mapping[int, str] = field(default_factory=dict)
    #: samples put per key through the link when the segment began (`flush_metrics`)
    sent_before: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.link is not None and not self.sent_before:
            self.sent_before = self.link.sent()

    def param(self, name: str) -> Any:
        """The value of parameter ``name``; a clear KeyError when the set does not provide it."""
        try:
            return self.params[name]
        except KeyError:
            raise KeyError(
                f"test case {self.case!r}, phase {self.phase!r}: parameter {name!r} "
                f"is not in this parameter set ({sorted(self.params)})"
            ) from None

    @property
    def stopped(self) -> bool:
        """True once the run (or the enclosing action) asked actions to finish early."""
        return self.stop.is_set()

    def require_link(self) -> Link:
        """The zenoh link, or a clear error when the action runs outside a test run."""
        if self.link is None:
            raise RuntimeError("this action talks over zenoh and needs a Context with a link")
        return self.link

    def with_stop(self, stop: threading.Event) -> Context:
        """A copy with its own stop signal, for actions that interrupt their children."""
        return replace(self, stop=stop)

    def child(self, deadline_ns: int | None = None) -> Context:
        """A copy whose stop signal is set by this one's, by its own ``set()``, or at a deadline
        (``time.perf_counter_ns()``); for actions that interrupt a subtree (LimitedTime...)."""
        return replace(self, stop=Stop(self.stop, deadline_ns))

    def sleep_until(self, deadline_ns: int) -> bool:
        """Wait until ``time.perf_counter_ns()`` reaches ``deadline_ns``; False if stopped first.

        Sleeps (interruptibly) to ~1 ms before the deadline, then spins for precision.
        """
        while True:
            remaining = deadline_ns - time.perf_counter_ns()
            if remaining <= SPIN_NS:
                break
            if self.stop.wait(min(remaining - SPIN_NS, 100_000_000) / 1e9):
                return False
        while time.perf_counter_ns() < deadline_ns:
            pass
        return not self.stop.is_set()

    def path_of(self, action: Any) -> str:
        """``action``'s place in the phase's tree; outside a phase (a unit test, a REPL) its
        class name, and a name given as text as it is."""
        if isinstance(action, str):
            return action
        return self.paths.get(id(action)) or type(action).__name__

    def tally(self, action: Any, key: str, measure: str = "rtt") -> Tally:
        """The `Tally` of ``action`` (an action of the tree, or a name) on ``key`` in this
        segment, created on first use."""
        ident = (self.path_of(action), key)
        found = self.tallies.get(ident)
        if found is None:
            name = action if isinstance(action, str) else type(action).__name__
            found = self.tallies.setdefault(ident, Tally(name, key, measure, path=ident[0]))
        return found

    def flush_metrics(self) -> None:
        """Report every tally of this segment, and the samples `Publish` put per key in it (the
        runner calls this when the segment ends)."""
        for ident in list(self.tallies):
            self.report(self.tallies.pop(ident).summary())
        if self.link is not None:
            for key, total in self.link.sent().items():
                published = total - self.sent_before.get(key, 0)
                if published:
                    self.report(
                        {"action": "Publish", "path": "Publish", "key": key, "published": published}
                    )
            self.sent_before = self.link.sent()

    def report(self, metrics: dict[str, Any], action: Any = None) -> None:
        """Record driver-side metrics of ``action`` (its path names them); published on
        ``@redline/driver/<case>/<phase>`` in a run."""
        path = self.path_of(action) if action is not None else metrics.get("path", "")
        message = {
            "t_ns": time.time_ns(),
            "case": self.case,
            "phase": self.phase,
            "params": dict(self.params),
            "path": path,
            **metrics,
        }
        self.reports.append(message)
        if self.link is not None:
            self.link.put_json(f"{DRIVER_PREFIX}{self.case}/{self.phase}", message)
