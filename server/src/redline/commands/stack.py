"""The whole service on one machine: what `redline up` starts and supervises.

Embedded Postgres and Redis unless `REDLINE_DATABASE_URL` / `REDLINE_REDIS_URL` are set, the
migrations, then the API server, a Celery worker and a local agent as child processes, each in its
own session so that a Ctrl-C reaches only this supervisor, which then stops them in order.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import httpx
from redline.agent.quiet import LOCK_VARIABLE
from redline.commands.embedded import (
    EmbeddedServices,
    start_postgres,
    start_redis,
    write_services,
)

#: the name the stack's agent registers as, and the one host its token may act as
AGENT_NAME = "local-agent"
STOP_TIMEOUT_S = 20.0
AGENT_FINISH_S = 5.0
BACKGROUND_NICE = 10


def redline_executable() -> str:
    found = Path(sys.executable).with_name("redline")
    return str(found) if found.exists() else shutil.which("redline") or "redline"


def server_only_variables() -> frozenset[str]:
    """The server's settings (`Settings`: its database and Redis, secrets, storage) that an
    agent does not read: the builds and components an agent runs inherit its environment (and
    their output reaches the pages), so it is given none of them."""
    from redline.server.core.config import Settings

    agent_reads = {"allow_file_repos"}
    return frozenset(
        f"REDLINE_{name.upper()}" for name in Settings.model_fields if name not in agent_reads
    )


class StackError(RuntimeError):
    """The stack could not start or a child died; the message says which and why."""


def port_free(port: int) -> None:
    """A `StackError` naming the way out when something already listens on ``port``."""
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", port))
        except OSError as exc:
            raise StackError(
                f"port {port} is taken ({exc.strerror}): another `redline up`, or another "
                "server; give this one another with --port"
            ) from None


def lock_data(data: Path) -> IO[bytes]:
    """Hold the data folder for this `redline up` while the returned file stays open: a second
    one on the same folder shared the first one's embedded Redis and, on its exit, stopped it,
    leaving the first unable to queue any work (a trial from outside, 2026-11-24)."""
    import fcntl

    handle = open(data / "lock", "a+b")  # noqa: SIM115 - held open for the stack's life
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().decode(errors="replace").strip() or "unknown"
        handle.close()
        raise StackError(
            f"the data folder {data} is in use by another `redline up` (pid {holder}): stop it "
            "first, or give this one its own --data"
        ) from None
    handle.truncate(0)
    handle.write(str(os.getpid()).encode())
    handle.flush()
    return handle


@dataclass
class Child:
    name: str
    process: subprocess.Popen[bytes]
    log_path: Path
    log: IO[bytes]

    def tail(self, lines: int = 15) -> str:
        text = self.log_path.read_text(errors="replace").splitlines()
        return "\n".join(text[-lines:])


@dataclass
class Stack:
    data: Path
    port: int
    children: list[Child] = field(default_factory=list)
    embedded: EmbeddedServices | None = None
    env: dict[str, str] = field(default_factory=dict)
    admin_token: str = ""
    lock: IO[bytes] | None = None  # the data folder's, held while the stack runs

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> None:
        # new, the data folder is its owner's only: it holds the database, recordings, tokens
        # (as root, pgserver opens the path to the user it runs Postgres as: see security.md)
        made = not self.data.exists()
        self.data.mkdir(mode=0o700, parents=True, exist_ok=True)
        self.lock = lock_data(self.data)
        try:
            port_free(self.port)  # before Postgres starts: seconds, and a page of its logs
        except StackError:
            if made:  # a refused start leaves no folder of its own (a trial's kept its lock)
                self.lock.close()
                self.lock = None
                (self.data / "lock").unlink()
                self.data.rmdir()
            raise
        (self.data / "logs").mkdir(mode=0o700, exist_ok=True)
        self.env = self._service_env()
        self._redline("migrate")
        self.admin_token = self.token("admin", "admin")
        agent = self.token("agent", "agent", host=AGENT_NAME)
        # On one machine, analysis must yield to measurement: the server and the worker run
        # at a lower priority than the agent, whose runs they would otherwise disturb.
        self._spawn(
            "server",
            "server",
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            nice=BACKGROUND_NICE,
        )
        self._wait_healthy()
        self._spawn(
            "worker", "worker", "--concurrency", "1", "--queues", "analysis", nice=BACKGROUND_NICE
        )
        self._spawn(
            "alerts",
            "worker",
            "--concurrency",
            "2",
            "--queues",
            "alerts",
            "--no-beat",
            nice=BACKGROUND_NICE,
        )
        # the agent last, once the workers have started: their start-up takes a core or two for
        # a few seconds, which the agent's first run would see as other load (and run again)
        for worker in ("worker", "alerts"):
            self._wait_logged(worker, " ready.")
        self._spawn(
            "agent",
            "agent",
            "--server",
            self.url,
            "--name",
            AGENT_NAME,
            "--work",
            str(self.data / "agent"),
            "--poll",
            "1",
            env={"REDLINE_TOKEN": agent},  # in its environment: argv is public (ps)
            without=server_only_variables(),
        )

    def _service_env(self) -> dict[str, str]:
        env = dict(os.environ)
        database = env.get("REDLINE_DATABASE_URL")
        redis = env.get("REDLINE_REDIS_URL")
        self.embedded = EmbeddedServices()
        started = {}
        if not database:
            database, self.embedded.postgres = start_postgres(self.data / "postgres")
            started["REDLINE_DATABASE_URL"] = database
        if not redis:
            redis, self.embedded.redis = start_redis(self.data / "redis")
            started["REDLINE_REDIS_URL"] = redis
        write_services(self.data, started)
        env.update(REDLINE_DATABASE_URL=database, REDLINE_REDIS_URL=redis)
        env.setdefault("REDLINE_STORAGE_DIR", str(self.data / "storage"))
        # one machine, one user: components may live in local repositories (the demo's does)
        env.setdefault("REDLINE_ALLOW_FILE_REPOS", "true")
        # agent and worker share this machine: analysis waits while a run measures (quiet.py)
        env.setdefault(LOCK_VARIABLE, str(self.data / "measurement.lock"))
        # one worker process: a re-analysis in more parts would only read each revision again
        env.setdefault("REDLINE_REANALYSIS_PARTS", "1")
        # links in alerts lead to the pages this stack serves (a trial's pointed at port 8000)
        env.setdefault("REDLINE_PUBLIC_URL", self.url)
        return env

    def _redline(self, *args: str) -> str:
        done = subprocess.run(
            [redline_executable(), *args], env=self.env, capture_output=True, text=True
        )
        if done.returncode != 0:
            raise StackError(f"`redline {' '.join(args)}` failed:\n{done.stderr.strip()}")
        return done.stdout.strip()

    def token(self, name: str, scopes: str, host: str | None = None) -> str:
        """The token kept in DIR/<name>-token (mode 600), created on first start; an agent
        token bound to ``host``, the one host it may act as."""
        path = self.data / f"{name}-token"
        if path.exists():
            return path.read_text().strip()
        bound = ["--host", host] if host else []
        token = self._redline(
            "token", "create", f"{name}-{int(time.time())}", "--scopes", scopes, *bound
        )
        token = token.splitlines()[-1].strip()
        path.touch(mode=0o600)
        path.write_text(token + "\n")
        return token

    def _spawn(
        self,
        name: str,
        *args: str,
        nice: int = 0,
        env: dict[str, str] | None = None,
        without: frozenset[str] = frozenset(),
    ) -> None:
        """Start ``redline ARGS`` logging to ``logs/NAME.log``, with the stack's environment
        less the variables ``without``, plus ``env``."""
        log_path = self.data / "logs" / f"{name}.log"
        log = open_private_log(log_path)
        inherited = {key: value for key, value in self.env.items() if key not in without}
        process = subprocess.Popen(
            [redline_executable(), *args],
            env={**inherited, **(env or {})},
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            preexec_fn=(lambda: os.nice(nice)) if nice else None,
        )
        self.children.append(Child(name, process, log_path, log))

    def _wait_healthy(self, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.check_children()
            try:
                if httpx.get(f"{self.url}/healthz", timeout=2).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.3)
        raise StackError(f"the API server did not answer {self.url}/healthz within {timeout:.0f}s")

    def _wait_logged(self, name: str, text: str, timeout: float = 90.0) -> None:
        """Wait until the child ``name`` has logged ``text`` (Celery's "celery@host ready.")."""
        child = next(c for c in self.children if c.name == name)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.check_children()
            if text in child.log_path.read_text(errors="replace"):
                return
            time.sleep(0.3)
        raise StackError(
            f"the {name} did not start within {timeout:.0f}s; its log ({child.log_path}) ends:\n"
            f"{child.tail()}"
        )

    def check_children(self) -> None:
        gone = self.embedded.gone() if self.embedded is not None else ""
        if gone:
            raise StackError(f"{gone}; start `redline up` again: its data in {self.data} is kept")
        for child in self.children:
            code = child.process.poll()
            if code is not None:
                raise StackError(
                    f"{child.name} exited with code {code}; the end of "
                    f"{child.log_path}:\n{child.tail()}"
                )

    def stop(self) -> None:
        """Stop the agent alone first, then the worker and the server, then Postgres and Redis.

        The agent gets AGENT_FINISH_S to finish its job; a second SIGTERM then makes it stop the
        run (whose component, recorder and monitor it takes down) and release the job. Only
        then go the worker and the server, which the agent still talks to until it is gone.
        """
        agents = [c for c in self.children if c.name == "agent"]
        for child in agents:
            _terminate(child, first_wait=AGENT_FINISH_S)
        for child in reversed([c for c in self.children if c.name != "agent"]):
            _terminate(child, first_wait=STOP_TIMEOUT_S)
        self.children.clear()
        if self.embedded is not None:
            self.embedded.stop()
            self.embedded = None
        if self.lock is not None:
            self.lock.close()  # the data folder is free again
            self.lock = None


def open_private_log(path: Path) -> IO[bytes]:
    """``path`` opened for appending, readable by its owner only (a log may quote a request)."""
    descriptor = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
    os.fchmod(descriptor, 0o600)  # a log made by an earlier version may be 644
    return os.fdopen(descriptor, "ab")


def _terminate(child: Child, first_wait: float) -> None:
    """SIGTERM, wait; SIGTERM again (an agent then releases its job), wait; then SIGKILL."""
    for wait in (first_wait, STOP_TIMEOUT_S):
        if child.process.poll() is not None:
            break
        child.process.send_signal(signal.SIGTERM)
        try:
            child.process.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
    if child.process.poll() is None:
        child.process.kill()
        child.process.wait()
    child.log.close()
