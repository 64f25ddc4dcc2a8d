"""Actions that talk to the component over zenoh."""

from __future__ import annotations

from typing import Any

from redline.testing.actions import Action, resolve
from redline.testing.context import Context


def as_payload(value: Any, key: str) -> bytes:
    """The bytes of a payload: bytes as they are, text as UTF-8; anything else is an error."""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value)
    if isinstance(value, str):
        return value.encode()
    raise TypeError(f"Publish({key!r}): payload must be bytes or str, got {type(value).__name__}")


class Publish(Action):
    """Publish one sample on ``key`` (the paper's InformerAction); returns the payload size.

    ``payload`` is bytes, text, or an action producing either (built afresh for every sample).
    ``key`` may also be an action, e.g. ``Param("key")``. Uses a declared publisher cached per
    key, with congestion control DROP: the driver never blocks on a slow component.
    """

    def __init__(self, key: str | Action, payload: bytes | str | Action,
                 *, encoding: str | None = None) -> None:
        self.key = key
        self.payload = payload
        self.encoding = encoding

    def run(self, ctx: Context) -> int:
        key = str(resolve(self.key, ctx))
        data = as_payload(resolve(self.payload, ctx), key)
        ctx.require_link().publisher(key, self.encoding).put(data)
        return len(data)
