"""A migrated, empty Postgres database for the server benchmarks (not a benchmark itself).

``REDLINE_DATABASE_URL`` when set (a fresh database is created on that server), else an embedded
pgserver in a temporary folder, removed afterwards.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import sqlalchemy as sa
from redline.server.db import migrate


def _on(url: str, name: str) -> str:
    base, _, query = url.partition("?")
    return base.rsplit("/", 1)[0] + f"/{name}" + (f"?{query}" if query else "")


@contextmanager
def database() -> Iterator[str]:
    """The URL of a new, migrated database; dropped (or its server removed) at the end."""
    from redline.commands.embedded import start_postgres

    configured = os.environ.get("REDLINE_DATABASE_URL")
    folder, handle = None, None
    if configured:
        server_url = configured
    else:
        folder = Path(tempfile.mkdtemp(prefix="redline-bench-pg-"))
        server_url, handle = start_postgres(folder / "data", "bench")
    name = f"redline_bench_{uuid.uuid4().hex[:8]}"
    admin = sa.create_engine(_on(server_url, "postgres"), isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(sa.text(f'CREATE DATABASE "{name}"'))
    url = _on(server_url, name)
    try:
        migrate(url)
        yield url
    finally:
        from redline.server.db import get_engine

        get_engine(url).dispose()
        with admin.connect() as conn:
            conn.execute(sa.text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()
        if handle is not None:
            handle.cleanup()
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def api_server(
    database_url: str, workers: int = 1, hosts: tuple[str, ...] = ()
) -> Iterator[tuple[str, dict[str, str]]]:
    """`redline server [--workers N]` on ``database_url`` as a child process: its URL and a token
    per scope, with an agent token per host of ``hosts`` (bound to it) as ``agent@HOST``."""
    from redline.agent.network import free_port
    from redline.commands.stack import Stack

    with tempfile.TemporaryDirectory() as tmp:
        stack = Stack(Path(tmp), free_port())
        (stack.data / "logs").mkdir(parents=True)
        stack.env = dict(
            os.environ,
            REDLINE_DATABASE_URL=database_url,
            REDLINE_STORAGE_DIR=str(stack.data / "storage"),
            REDLINE_LEASE_SECONDS="600",
        )
        tokens = {scope: stack.token(scope, scope) for scope in ("admin", "ci", "read")}
        tokens |= {f"agent@{host}": stack.token(host, "agent", host) for host in hosts}
        stack._spawn(
            "server", "server", "--host", "127.0.0.1", "--port", str(stack.port),
            "--workers", str(workers),
        )  # fmt: skip
        try:
            stack._wait_healthy()
            yield stack.url, tokens
        finally:
            stack.stop()
