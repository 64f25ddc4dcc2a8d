"""Payloads built from templates and scaled by parameters (the paper's DynamicEvent, ProtobufData).

A template is plain data (dicts, lists, numbers, text) in which any value may be an action: a
`Param`, a `Repeated` list whose length is a parameter, a `Filler` string of a given size, or
your own action. `Message.json`, `Message.protobuf` and `Message.raw` turn it into a `Payload`:
bytes that carry their zenoh encoding, which `Publish` and `Query` put on the sample.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from redline.testing.actions import Action, resolve
from redline.testing.context import Context


class Payload(bytes):
    """Bytes with the zenoh encoding they should be sent with."""

    encoding: str | None = None

    @classmethod
    def of(cls, data: bytes, encoding: str | None) -> Payload:
        payload = cls(data)
        payload.encoding = encoding
        return payload


def build(template: Any, ctx: Context) -> Any:
    """The value of a template for the parameter set in ``ctx``: actions run, containers walked."""
    if isinstance(template, Action):
        return build(template.run(ctx), ctx)
    if isinstance(template, dict):
        return {key: build(value, ctx) for key, value in template.items()}
    if isinstance(template, (list, tuple)):
        return [build(value, ctx) for value in template]
    return template


class Repeated(Action):
    """A list of ``count`` items (a number or ``Param``); the paper's scaled repeated field.

    ``item`` is a template copied for every element, or a generator called with the element's
    index that returns one: ``Repeated(lambda i: {"x": i * 0.3, "y": 1.0}, Param("legs"))``.
    """

    def __init__(self, item: Any, count: int | Action) -> None:
        self.item = item
        self.count = count

    def run(self, ctx: Context) -> list[Any]:
        count = int(resolve(self.count, ctx))
        if count < 0:
            raise ValueError(f"Repeated count must not be negative, got {count}")
        if callable(self.item) and not isinstance(self.item, Action):
            generate: Callable[[int], Any] = self.item
            return [build(generate(index), ctx) for index in range(count)]
        return [build(self.item, ctx) for _ in range(count)]


class Filler(Action):
    """A string of ``size`` characters (a number or ``Param``): a scaled string field."""

    def __init__(self, size: int | Action, char: str = "x") -> None:
        self.size = size
        self.char = char

    def run(self, ctx: Context) -> str:
        return self.char * int(resolve(self.size, ctx))


class Message(Action):
    """A payload built from a template for every run; subclass it and implement `encode` for
    another wire format. Use the constructors: `Message.json`, `Message.protobuf`, `Message.raw`.
    """

    encoding: str | None = None

    def __init__(self, template: Any) -> None:
        self.template = template

    def encode(self, value: Any) -> bytes:
        """The bytes of a built template."""
        raise NotImplementedError(f"{type(self).__name__} must implement encode(value)")

    def run(self, ctx: Context) -> Payload:
        return Payload.of(self.encode(build(self.template, ctx)), self.encoding)

    @staticmethod
    def json(template: Any) -> Message:
        """JSON text of the template, encoding ``application/json``."""
        return JsonMessage(template)

    @staticmethod
    def raw(size: int | Action, fill: bytes = b"\0") -> Message:
        """``size`` bytes (a number or ``Param``) of ``fill``; ``application/octet-stream``."""
        return RawMessage(size, fill)

    @staticmethod
    def protobuf(message_class: Any, template: Any) -> Message:
        """A protobuf message of ``message_class`` filled from the template (field names as keys,
        `Repeated` for repeated fields), serialized; encoding ``application/protobuf;<full name>``.
        """
        return ProtobufMessage(message_class, template)


class JsonMessage(Message):
    encoding = "application/json"

    def encode(self, value: Any) -> bytes:
        return json.dumps(value, separators=(",", ":")).encode()


class RawMessage(Message):
    encoding = "application/octet-stream"

    def __init__(self, size: int | Action, fill: bytes = b"\0") -> None:
        super().__init__(size)
        if not isinstance(fill, bytes) or len(fill) != 1:
            raise TypeError(f"Message.raw fill must be one byte, got {fill!r}")
        self.fill = fill
        self._cache: dict[int, Payload] = {}  # immutable, so one object per size serves every run

    def run(self, ctx: Context) -> Payload:
        size = int(resolve(self.template, ctx))
        found = self._cache.get(size)
        if found is None:
            if size < 0:
                raise ValueError(f"Message.raw size must not be negative, got {size}")
            found = self._cache.setdefault(size, Payload.of(self.fill * size, self.encoding))
        return found


class ProtobufMessage(Message):
    def __init__(self, message_class: Any, template: Any) -> None:
        super().__init__(template)
        descriptor = getattr(message_class, "DESCRIPTOR", None)
        if descriptor is None:
            raise TypeError(
                f"Message.protobuf needs a protobuf message class, got {message_class!r}"
            )
        self.message_class = message_class
        self.encoding = f"application/protobuf;{descriptor.full_name}"

    def encode(self, value: Any) -> bytes:
        from google.protobuf import json_format

        message = self.message_class()
        json_format.ParseDict(value, message)
        return bytes(message.SerializeToString())
