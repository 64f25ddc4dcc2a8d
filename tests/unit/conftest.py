"""Unit tests need no service and no network: any attempt to reach one fails the test loudly.

Every `connect` of an IP or Unix socket, every datagram sent to an address and every zenoh
session opened in the test's process raises `NetworkUsed` naming what was tried. A test that
needs Postgres, Redis, zenoh or any server belongs in `tests/integration`.
"""

from __future__ import annotations

import socket
from collections.abc import Callable
from typing import Any, NoReturn

import pytest

BLOCKED = (socket.AF_INET, socket.AF_INET6, socket.AF_UNIX)
MOVE = "unit tests use no service and no network: move this test to tests/integration"


class NetworkUsed(AssertionError):
    """A unit test tried to reach a service or the network."""


def _refused(what: str) -> NoReturn:
    raise NetworkUsed(f"{what}: {MOVE}")


def _guarded(original: Callable[..., Any], verb: str) -> Callable[..., Any]:
    def guard(self: socket.socket, address: Any, *args: Any) -> Any:
        if self.family in BLOCKED:
            _refused(f"{verb} to {address!r}")
        return original(self, address, *args)

    return guard


def _sendto(original: Callable[..., Any]) -> Callable[..., Any]:
    def guard(self: socket.socket, data: Any, *args: Any) -> Any:
        if self.family in BLOCKED:
            _refused(f"sendto {args[-1]!r}")
        return original(self, data, *args)

    return guard


@pytest.fixture(autouse=True)
def no_network(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(socket.socket, "connect", _guarded(socket.socket.connect, "connect"))
    monkeypatch.setattr(socket.socket, "connect_ex", _guarded(socket.socket.connect_ex, "connect"))
    monkeypatch.setattr(socket.socket, "sendto", _sendto(socket.socket.sendto))
    import zenoh

    def no_zenoh(*_args: Any, **_kwargs: Any) -> NoReturn:
        _refused("zenoh.open")

    monkeypatch.setattr(zenoh, "open", no_zenoh)


@pytest.fixture(scope="session")
def services() -> NoReturn:
    """Shadows the integration tests' real Postgres and Redis, which unit tests may not use."""
    pytest.fail(f"the `services` fixture (Postgres, Redis): {MOVE}", pytrace=False)
