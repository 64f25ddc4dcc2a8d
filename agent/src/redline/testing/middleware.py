"""Actions that send to the component over zenoh: Publish and Query."""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Any

import zenoh
from redline.testing.actions import Action, resolve
from redline.testing.context import Context
from redline.testing.metrics import Tally


def as_payload(value: Any, key: str, action: str = "Publish") -> bytes:
    """The bytes of a payload: bytes as they are, text as UTF-8; anything else is an error."""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return value if type(value) is bytes else bytes(value)
    if isinstance(value, str):
        return value.encode()
    raise TypeError(f"{action}({key!r}): payload must be bytes or str, got {type(value).__name__}")


def key_problems(action: str, *keys: object) -> list[str]:
    """Why each literal key expression of an action is malformed (keys given as actions, such as
    ``Param("key")``, are checked by zenoh when the action runs)."""
    found = []
    for key in keys:
        if isinstance(key, str):
            try:
                zenoh.KeyExpr(key)
            except zenoh.ZError as exc:
                reason = str(exc).split(": ", 1)[-1].split(" at /", 1)[0]  # drop the Rust path
                found.append(f"{action}: {key!r} is not a valid key expression ({reason})")
    return found


def encoding_of(data: Any, given: str | None) -> str | None:
    """The encoding given to the action, else the one a `Message` payload carries."""
    return given if given is not None else getattr(data, "encoding", None)


class Publish(Action):
    """Publish one sample on ``key`` (the paper's InformerAction); returns the payload size.

    ``payload`` is bytes, text, or an action producing either (built afresh for every sample,
    e.g. a `Message`, whose encoding is used unless ``encoding`` is given). ``key`` may also be an
    action, e.g. ``Param("key")``. Uses a declared publisher cached per key, with congestion
    control DROP: the driver never blocks on a slow component. With ``sequence=True`` every sample
    carries its sequence number on that key (0, 1, 2, ... as ASCII digits) as its zenoh
    attachment, so `Listen` can count what was lost on the way. The link counts the samples put
    per key and tells the recorder at the end of the run, which writes what never reached it
    into the recording (``lost_by_key`` in ``redline.recorder``).
    """

    def __init__(
        self,
        key: str | Action,
        payload: bytes | str | Action,
        *,
        encoding: str | None = None,
        sequence: bool = False,
    ) -> None:
        self.key = key
        self.payload = payload
        self.encoding = encoding
        self.sequence = sequence

    def problems(self) -> list[str]:
        return key_problems("Publish", self.key)

    @property
    def cheap(self) -> bool:  # type: ignore[override]
        """A literal key and payload: a run is one put on a cached publisher."""
        return (
            isinstance(self.key, str) and not isinstance(self.payload, Action) and not self.sequence
        )

    def compile(self, ctx: Context) -> Callable[[], Any]:
        if not self.cheap:
            return super().compile(ctx)
        key = str(self.key)
        payload = as_payload(self.payload, key)
        link = ctx.require_link()
        publisher = link.publisher(key, encoding_of(self.payload, self.encoding))
        step = functools.partial(publisher.put, payload)  # no per-run Python in between
        step.ran = functools.partial(link.count_sent, key)  # type: ignore[attr-defined]
        return step

    def run(self, ctx: Context) -> int:
        key = str(resolve(self.key, ctx))
        data = resolve(self.payload, ctx)
        payload = as_payload(data, key)
        link = ctx.require_link()
        publisher = link.publisher(key, encoding_of(data, self.encoding))
        if self.sequence:
            publisher.put(payload, attachment=str(link.next_sequence(key)).encode())
        else:
            publisher.put(payload)
        link.count_sent(key)
        return len(payload)


class Query(Action):
    """Send a zenoh ``get`` to a queryable (the paper's RpcAction).

    With ``wait=True`` (the default) waits for the replies and returns the first reply's payload
    (None when there was none). With ``wait=False`` returns at once and the replies are counted
    as they arrive. Nothing is raised for a missing reply: per key and segment the driver reports
    ``queries`` (sent), ``count`` (round trips measured), ``timeouts``, ``errors`` (error
    replies), ``unanswered`` (no queryable matched) and round-trip percentiles ``rtt_p50_us``
    ... ``rtt_max_us`` on ``@redline/driver/<case>/<phase>``. ``timeout`` is in seconds;
    ``payload`` may be a `Message`.
    """

    def __init__(
        self,
        key: str | Action,
        payload: bytes | str | Action | None = None,
        *,
        timeout: float | Action = 1.0,
        wait: bool = True,
        encoding: str | None = None,
    ) -> None:
        self.key = key
        self.payload = payload
        self.timeout = timeout
        self.wait = wait
        self.encoding = encoding

    def problems(self) -> list[str]:
        return key_problems("Query", self.key)

    def run(self, ctx: Context) -> bytes | None:
        key = str(resolve(self.key, ctx))
        data = resolve(self.payload, ctx)
        options: dict[str, Any] = {"timeout": float(resolve(self.timeout, ctx))}
        if data is not None:
            options["payload"] = as_payload(data, key, "Query")
            encoding = encoding_of(data, self.encoding)
            if encoding is not None:
                options["encoding"] = encoding
        session = ctx.require_link().session
        round_trip = _RoundTrip(ctx.tally(self, key))
        round_trip.tally.count("queries")
        if not self.wait:
            session.get(key, zenoh.handlers.Callback(round_trip.take, round_trip.done), **options)
            return None
        for reply in session.get(key, **options):
            round_trip.take(reply)
        round_trip.done()
        return round_trip.first


class _RoundTrip:
    """One query's replies: the first ok reply's round trip and payload, timeouts and errors."""

    def __init__(self, tally: Tally) -> None:
        self.tally = tally
        self.began = time.perf_counter_ns()
        self.first: bytes | None = None
        self.replies = 0

    def take(self, reply: zenoh.Reply) -> None:
        self.replies += 1
        if reply.ok is not None:
            if self.first is None:
                self.tally.add(time.perf_counter_ns() - self.began)
                self.first = reply.ok.payload.to_bytes()
            return
        error = reply.err.payload.to_bytes() if reply.err is not None else b""
        self.tally.count("timeouts" if error == b"Timeout" else "errors")

    def done(self) -> None:
        if self.replies == 0:
            self.tally.count("unanswered")
