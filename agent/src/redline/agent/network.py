"""The isolated zenoh network of one test run.

Each run opens its own zenoh router, on a free loopback TCP port (``transport="tcp"``, the
default) or on a unix socket in a private folder (``transport="unix"``, endpoint
``unixsock-stream/PATH``: no port at all). Components get a peer configuration through
``ZENOH_CONFIG`` (a file path, read by ``zenoh.Config.from_env()``); Redline's own processes
(driver, recorder, monitor) connect as clients. Multicast scouting is off and every endpoint is
on 127.0.0.1 or a unix socket, so nothing leaves the host and two runs never hear each other.
Gossip scouting stays on: it travels only over the run's own links and is how peers learn each
other's loopback endpoints (without it, two peers connected to one router cannot reach each
other, measured with zenoh 1.6). With unix sockets peers do not listen (a shared configuration
cannot give each its own socket path), so their traffic goes through the router.

Shared memory (zenoh's default, for payloads of ~3 KiB and more between local processes) changes
large-message throughput ~10x, so it is an explicit setting of the run, the same for every
process, and the recorder writes it into the recording.

The router notes the zenoh id of every session that connects to it (`RunNetwork.sessions_seen`)
and, through its admin space (read-only, its own), who subscribed to what
(`RunNetwork.subscriptions`); Redline's own processes get ids chosen for them (`session_id`), so
any other id is a process of the suite that joined the network.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import socket
import tempfile
from pathlib import Path
from typing import Any

import zenoh

TRANSPORTS = ("tcp", "unix")
#: Batches queued per link for data (zenoh's default: 2, ~128 KiB, which a receiver paused for a
#: millisecond overflows at 100,000 msg/s of 1 KiB, and DROP publishers then lose samples).
DATA_QUEUE_BATCHES = 16
#: Ports a router tries: one chosen free may be taken before the router binds it (another run's
#: router, a component's peer; a CI run's three agents on one host failed a job so)
PORT_TRIES = 5
IN_USE = "Address already in use"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _isolated(
    mode: str, listen: list[str], connect: list[str], shared_memory: bool
) -> dict[str, Any]:
    return {
        "mode": mode,
        "listen": {"endpoints": listen},
        "connect": {"endpoints": connect},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True}},
        "transport": {
            "shared_memory": {"enabled": shared_memory},
            "link": {"tx": {"queue": {"size": {"data": DATA_QUEUE_BATCHES}}}},
        },
    }


def session_id() -> str:
    """A fresh zenoh session id (32 hex digits; zenoh refuses a leading 0)."""
    return f"{secrets.randbits(128) | 1 << 127:032x}"


def config_from_dict(settings: dict[str, Any]) -> zenoh.Config:
    config = zenoh.Config()
    for key in ("mode", "listen", "connect", "scouting"):
        config.insert_json5(key, json.dumps(settings[key]))
    if "id" in settings:
        config.insert_json5("id", json.dumps(settings["id"]))
    if "transport" in settings:  # merged with zenoh's defaults for what it leaves out
        config.insert_json5("transport", json.dumps(settings["transport"]))
    if "adminspace" in settings:
        config.insert_json5("adminspace", json.dumps(settings["adminspace"]))
    return config


def shared_memory_enabled(settings: dict[str, Any]) -> bool:
    """Whether zenoh shared memory is on for these settings (zenoh's default when not given)."""
    given = settings.get("transport", {}).get("shared_memory", {}).get("enabled")
    if given is not None:
        return bool(given)
    return bool(json.loads(zenoh.Config().get_json("transport/shared_memory/enabled")))


class RunNetwork:
    """Owns the run's router session; hands out configurations for everything else."""

    def __init__(
        self, port: int | None = None, *, transport: str = "tcp", shared_memory: bool = True
    ) -> None:
        if transport not in TRANSPORTS:
            raise ValueError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
        self.transport = transport
        self.shared_memory = shared_memory
        self._folder: Path | None = None
        if transport == "unix":
            # a short private path: unix socket paths are limited to ~107 bytes
            self._folder = Path(tempfile.mkdtemp(prefix="redline-zenoh-"))
            self.endpoint = f"unixsock-stream/{self._folder / 'router.sock'}"
        else:
            self.endpoint = f"tcp/127.0.0.1:{port or free_port()}"
        self._chosen = transport == "tcp" and not port  # a port of its own choosing: may move
        self._router: zenoh.Session | None = None
        self._seen: set[str] = set()

    def open(self) -> RunNetwork:
        for tries_left in reversed(range(PORT_TRIES if self._chosen else 1)):
            settings = _isolated("router", [self.endpoint], [], self.shared_memory)
            # read-only, for the runner's own router session: who subscribed to what
            settings["adminspace"] = {
                "enabled": True,
                "permissions": {"read": True, "write": False},
            }
            try:
                self._router = zenoh.open(config_from_dict(settings))
                break
            except zenoh.ZError as exc:  # taken between choosing and binding it: choose again
                if IN_USE not in str(exc) or not tries_left:
                    raise
                self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        assert self._router is not None
        self._router.info.declare_transport_events_listener(  # lives as long as the router
            lambda event: self._seen.add(str(event.transport.zid)), history=True
        )
        return self

    def sessions_seen(self) -> set[str]:
        """The ids of every zenoh session that has connected to the router since it opened
        (whether or not it is still connected)."""
        return set(self._seen)

    def subscriptions(self) -> dict[str, set[str]]:
        """Every key expression subscribed to on the network now, with the ids of the sessions
        that subscribed to it (the router's admin space, less the router itself, which it lists
        as the source of all it passes on)."""
        assert self._router is not None, "the network is not open"
        router = str(self._router.info.zid())
        prefix = f"@/{router}/router/subscriber/"
        found: dict[str, set[str]] = {}
        for reply in self._router.get(prefix + "**", timeout=2.0):
            if reply.ok is not None:  # {"routers": [zid, ...], "peers": [...], "clients": [...]}
                sources = json.loads(reply.ok.payload.to_bytes())
                zids = {str(zid) for group in sources.values() for zid in group} - {router}
                found[str(reply.ok.key_expr).removeprefix(prefix)] = zids
        return found

    def close(self) -> None:
        if self._router is not None:
            self._router.close()
            self._router = None
        if self._folder is not None:
            shutil.rmtree(self._folder, ignore_errors=True)
            self._folder = None

    def __enter__(self) -> RunNetwork:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def peer_settings(self) -> dict[str, Any]:
        """What a component gets: a peer that listens on an ephemeral loopback port (TCP), or
        does not listen (unix sockets), connected to the router."""
        listen = ["tcp/127.0.0.1:0"] if self.transport == "tcp" else []
        return _isolated("peer", listen, [self.endpoint], self.shared_memory)

    def client_settings(self, zid: str | None = None) -> dict[str, Any]:
        """What Redline's own processes get: a client of the router, with id ``zid`` if given."""
        settings = _isolated("client", [], [self.endpoint], self.shared_memory)
        return settings if zid is None else {**settings, "id": zid}

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
