"""Separate "hosts" on one machine: network namespaces joined to this one by veth pairs (`ip
netns`, as root), and a relay that serves a service of this host (Postgres, Redis: on TCP or a
unix socket) on an address the other hosts reach over their veth.

A unix socket is a file, which a network namespace does not hide: the relay makes the other
hosts reach this host's services over the network, as separate machines would.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import threading
from dataclasses import dataclass
from pathlib import Path

SUBNET = "10.231"


def why_not_allowed() -> str | None:
    """Why network namespaces cannot be made here (None: they can)."""
    if os.geteuid() != 0:
        return "network namespaces need root (ip netns)"
    if shutil.which("ip") is None:
        return "no `ip` command (iproute2)"
    probe = f"redline-probe-{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"ip netns add is not allowed here: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def _ip(*args: str, namespace: str | None = None) -> None:
    prefix = ["ip", "netns", "exec", namespace] if namespace else []
    subprocess.run([*prefix, "ip", *args], check=True, capture_output=True, text=True)


@dataclass
class Host:
    """A network namespace at ``SUBNET.<index>.2``, joined to this host (``SUBNET.<index>.1``)."""

    role: str
    index: int

    @property
    def name(self) -> str:
        return f"redline-{self.role}-{os.getpid()}"

    @property
    def address(self) -> str:
        return f"{SUBNET}.{self.index}.2"

    @property
    def gateway(self) -> str:
        """This host's address, as the namespace reaches it."""
        return f"{SUBNET}.{self.index}.1"

    @property
    def _links(self) -> tuple[str, str]:
        stem = f"rl{os.getpid() % 100000}{self.index}"  # interface names: 15 characters at most
        return f"{stem}h", f"{stem}n"

    def create(self) -> None:
        self.delete()
        outside, inside = self._links
        _ip("netns", "add", self.name)
        _ip("link", "add", outside, "type", "veth", "peer", "name", inside)
        _ip("link", "set", inside, "netns", self.name)
        _ip("addr", "add", f"{self.gateway}/24", "dev", outside)
        _ip("link", "set", outside, "up")
        _ip("addr", "add", f"{self.address}/24", "dev", inside, namespace=self.name)
        _ip("link", "set", inside, "up", namespace=self.name)
        _ip("link", "set", "lo", "up", namespace=self.name)

    def delete(self) -> None:
        subprocess.run(["ip", "netns", "del", self.name], capture_output=True)
        subprocess.run(["ip", "link", "del", self._links[0]], capture_output=True)

    def popen(self, argv: list[str], log: Path, env: dict[str, str]) -> subprocess.Popen:
        """``argv`` run in the namespace, in a process group of its own (killed with it)."""
        return subprocess.Popen(
            ["ip", "netns", "exec", self.name, *argv],
            env=env,
            stdout=log.open("ab"),
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )


class Relay:
    """Serves ``target`` (a (host, port) or a unix socket's path) on every address of this host,
    at ``port``: each connection relayed both ways until either side closes."""

    def __init__(self, target: tuple[str, int] | str) -> None:
        self.target = target
        self.server = socket.create_server(("0.0.0.0", 0))
        self.port = self.server.getsockname()[1]
        threading.Thread(target=self._accept, daemon=True).start()

    def _connect(self) -> socket.socket:
        if isinstance(self.target, str):
            far = socket.socket(socket.AF_UNIX)
            far.connect(self.target)
            return far
        return socket.create_connection(self.target)

    def _accept(self) -> None:
        while True:
            try:
                near, _ = self.server.accept()
            except OSError:
                return  # closed
            try:
                far = self._connect()
            except OSError:
                near.close()
                continue
            for source, sink in ((near, far), (far, near)):
                threading.Thread(target=_pump, args=(source, sink), daemon=True).start()

    def close(self) -> None:
        self.server.close()


def _pump(source: socket.socket, sink: socket.socket) -> None:
    try:
        while data := source.recv(65536):
            sink.sendall(data)
    except OSError:
        pass
    finally:
        for end in (source, sink):
            with contextlib.suppress(OSError):
                end.shutdown(socket.SHUT_RDWR)
