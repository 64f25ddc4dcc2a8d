"""Actions that receive from the component over zenoh: WaitFor and Listen."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh
from redline.testing.actions import Action, resolve
from redline.testing.context import Context
from redline.testing.middleware import key_problems

Predicate = Callable[[bytes], bool]


class WaitFor(Action):
    """Wait for a sample on ``key`` (the paper's WaitEvent); returns its payload, None on timeout.

    ``key`` is a key expression (``robot/*/pose`` works). ``where`` is an optional predicate on the
    payload bytes; samples it rejects are ignored. ``after`` is an optional action run once the
    subscription is in place, so a reply to it cannot be missed::

        WaitFor("echo/out", 1.0, after=Publish("echo/in", b"ping"))

    A timeout is counted, never raised: per key and segment the driver reports ``waits``,
    ``timeouts`` and the wait time percentiles ``wait_p50_us``... on ``@redline/driver/...``.
    """

    def __init__(
        self,
        key: str | Action,
        timeout: float | Action = 1.0,
        *,
        where: Predicate | None = None,
        after: Action | None = None,
    ) -> None:
        self.key = key
        self.timeout = timeout
        self.where = where
        self.after = after

    def problems(self) -> list[str]:
        return key_problems("WaitFor", self.key)

    def run(self, ctx: Context) -> bytes | None:
        key = str(resolve(self.key, ctx))
        timeout = float(resolve(self.timeout, ctx))
        tally = ctx.tally(self, key, "wait")
        tally.count("waits")
        found: list[bytes] = []
        arrived = threading.Event()

        def take(sample: zenoh.Sample) -> None:
            data = sample.payload.to_bytes()
            if not arrived.is_set() and (self.where is None or self.where(data)):
                found.append(data)
                arrived.set()

        forget = ctx.require_link().listen(key, take)
        try:
            began = time.perf_counter_ns()
            if self.after is not None:
                self.after.run(ctx)
            deadline = began + int(timeout * 1e9)
            while not arrived.is_set() and not ctx.stopped:
                remaining = (deadline - time.perf_counter_ns()) / 1e9
                if remaining <= 0:
                    break
                arrived.wait(min(remaining, 0.05))
        finally:
            forget()
        if not found:
            tally.count("interrupted" if ctx.stopped else "timeouts")
            return None
        tally.add(time.perf_counter_ns() - began)
        return found[0]


class _Arrivals:
    """Per concrete key: samples received and the sequence numbers their attachments carried."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.received: dict[str, int] = {}
        self.sequences: dict[str, set[int]] = {}

    def __call__(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        number = _sequence_number(sample.attachment)
        with self.lock:
            self.received[key] = self.received.get(key, 0) + 1
            if number is not None:
                self.sequences.setdefault(key, set()).add(number)

    def summary(self, key: str, seconds: float) -> dict[str, Any]:
        with self.lock:
            received = self.received.get(key, 0)
            numbers = self.sequences.get(key)
        result: dict[str, Any] = {
            "action": "Listen",
            "key": key,
            "received": received,
            "rate": received / seconds if seconds > 0 else 0.0,
        }
        if numbers:
            expected = max(numbers) - min(numbers) + 1
            result |= {
                "sequenced": len(numbers),
                "expected": expected,
                "lost": expected - len(numbers),
                "loss_ratio": (expected - len(numbers)) / expected,
                "duplicates": received - len(numbers),
            }
        return result


def _sequence_number(attachment: zenoh.ZBytes | None) -> int | None:
    if attachment is None:
        return None
    text = attachment.to_bytes()
    return int(text) if text.isdigit() else None


class Listen(Action):
    """Count the samples on ``key`` while ``during`` runs; returns the number received.

    Reports per concrete key (a wildcard ``key`` may match several): ``received`` and ``rate``
    (samples/s while ``during`` ran), and, when the samples carry sequence numbers as their
    attachment (see ``Publish(..., sequence=True)``; a component can pass them on), ``lost``
    (gaps between the lowest and highest number seen), ``loss_ratio`` and ``duplicates``.
    ``grace`` seconds after ``during`` ends let samples still in flight arrive::

        Listen("echo/out", FixedRate(100, 5, Publish("echo/in", b"x", sequence=True)))
    """

    def __init__(self, key: str | Action, during: Action, *, grace: float = 0.2) -> None:
        if not isinstance(during, Action):
            raise TypeError(f"Listen runs an action while it listens, got {during!r}")
        self.key = key
        self.during = during
        self.grace = grace

    def problems(self) -> list[str]:
        return key_problems("Listen", self.key)

    def run(self, ctx: Context) -> int:
        key = str(resolve(self.key, ctx))
        arrivals = _Arrivals()
        forget = ctx.require_link().listen(key, arrivals)
        began = time.perf_counter()
        try:
            self.during.run(ctx)
            seconds = time.perf_counter() - began  # the rate is over ``during``, not the grace
            ctx.sleep_until(time.perf_counter_ns() + int(self.grace * 1e9))
        finally:
            forget()
        for concrete in sorted(arrivals.received) or [key]:
            ctx.report(arrivals.summary(concrete, seconds), action=self)
        return sum(arrivals.received.values())
