"""The isolated zenoh network of one test run.

Each run opens its own zenoh router on a free loopback port. Components get a peer configuration
through ``ZENOH_CONFIG`` (a file path, read by ``zenoh.Config.from_env()``); Redline's own processes
(driver, recorder, monitor) connect as clients. Multicast scouting is off and every endpoint is on
127.0.0.1, so nothing leaves the host and two runs never hear each other. Gossip scouting stays on:
it travels only over the run's own links and is how peers learn each other's loopback endpoints
(without it, two peers connected to one router cannot reach each other, measured with zenoh 1.6).
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path
from typing import Any

import zenoh


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _isolated(mode: str, listen: list[str], connect: list[str]) -> dict[str, Any]:
    return {
        "mode": mode,
        "listen": {"endpoints": listen},
        "connect": {"endpoints": connect},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True}},
    }


def config_from_dict(settings: dict[str, Any]) -> zenoh.Config:
    config = zenoh.Config()
    for key in ("mode", "listen", "connect", "scouting"):
        config.insert_json5(key, json.dumps(settings[key]))
    return config


class RunNetwork:
    """Owns the run's router session; hands out configurations for everything else."""

    def __init__(self, port: int | None = None) -> None:
        self.endpoint = f"tcp/127.0.0.1:{port or free_port()}"
        self._router: zenoh.Session | None = None

    def open(self) -> RunNetwork:
        self._router = zenoh.open(config_from_dict(_isolated("router", [self.endpoint], [])))
        return self

    def close(self) -> None:
        if self._router is not None:
            self._router.close()
            self._router = None

    def __enter__(self) -> RunNetwork:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def peer_settings(self) -> dict[str, Any]:
        """What a component gets: a peer that listens on an ephemeral loopback port."""
        return _isolated("peer", ["tcp/127.0.0.1:0"], [self.endpoint])

    def client_settings(self) -> dict[str, Any]:
        return _isolated("client", [], [self.endpoint])

    def write_component_config(self, path: Path) -> Path:
        path.write_text(json.dumps(self.peer_settings(), indent=2))
        return path

    def component_env(self, path: Path) -> dict[str, str]:
        return {"ZENOH_CONFIG": str(self.write_component_config(path))}


def open_client(settings: dict[str, Any]) -> zenoh.Session:
    return zenoh.open(config_from_dict(settings))


def client_settings_from_env(variable: str = "REDLINE_ZENOH") -> dict[str, Any]:
    """Redline's helper processes get their client settings as JSON in an environment variable."""
    return dict(json.loads(os.environ[variable]))
