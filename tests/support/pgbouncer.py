"""A real PgBouncer (Debian's, installed by `run.py test`) in transaction mode, in front of the
Postgres behind a test's database URL, for as long as a ``with`` block runs."""

from __future__ import annotations

import os
import pwd
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import psycopg
from redline.agent.network import free_port

from tests.support import stop

PGBOUNCER = "/usr/sbin/pgbouncer"


def _server_user(socket_folder: str | None) -> str | None:
    """Who PgBouncer runs as when we are root (it refuses to run as root): the owner of the
    Postgres socket's folder, who can reach the socket (the embedded server's user), else
    nobody; None when we are not root."""
    if os.geteuid() != 0:
        return None
    if socket_folder:
        return pwd.getpwuid(Path(socket_folder).stat().st_uid).pw_name
    return "nobody"


@contextmanager
def pgbouncer(database_url: str, pool_size: int = 2) -> Iterator[str]:
    """Yield ``database_url`` as reached through a PgBouncer in transaction mode whose pools
    hold ``pool_size`` server connections per database and user (fewer than the clients, so
    that clients take turns on the same server connections, as in production)."""
    parts = urlsplit(database_url)
    socket_folder = parse_qs(parts.query).get("host", [None])[0]
    host = socket_folder or parts.hostname or "127.0.0.1"
    user = parts.username or "postgres"
    port = free_port()
    folder = Path(tempfile.mkdtemp(prefix="redline-pgbouncer-"))
    folder.chmod(0o755)  # PgBouncer drops to another user, who must write its log here
    (folder / "users.txt").write_text(f'"{user}" ""\n')
    (folder / "pgbouncer.ini").write_text(
        "[databases]\n"
        f"* = host={host} port={parts.port or 5432}\n"
        "[pgbouncer]\n"
        f"listen_addr = 127.0.0.1\nlisten_port = {port}\nunix_socket_dir =\n"
        f"auth_type = trust\nauth_file = {folder / 'users.txt'}\n"
        f"pool_mode = transaction\ndefault_pool_size = {pool_size}\nmax_client_conn = 500\n"
        f"logfile = {folder / 'pgbouncer.log'}\n"
    )
    server_user = _server_user(socket_folder)
    if server_user is not None:
        shutil.chown(folder, user=server_user)
    command = [PGBOUNCER, *(["-u", server_user] if server_user else []), "pgbouncer.ini"]
    process = subprocess.Popen(
        command, cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    through = parts._replace(netloc=f"{user}@127.0.0.1:{port}", query="").geturl()
    try:
        _wait_until_up(process, through, folder)
        yield through
    finally:
        stop(process)
        shutil.rmtree(folder, ignore_errors=True)


def _wait_until_up(process: subprocess.Popen[str], url: str, folder: Path) -> None:
    plain = url.replace("postgresql+psycopg://", "postgresql://", 1)
    deadline = time.monotonic() + 15
    while True:
        if process.poll() is not None:
            log = folder / "pgbouncer.log"
            said = (process.stderr.read() if process.stderr else "") + (
                log.read_text() if log.exists() else ""
            )
            raise RuntimeError(f"pgbouncer exited {process.returncode}: {said}")
        try:
            with psycopg.connect(plain, connect_timeout=2) as connection:
                connection.execute("SELECT 1")
            return
        except psycopg.OperationalError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
