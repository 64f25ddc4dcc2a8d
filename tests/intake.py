"""A driver for the HTTP API with settings of the test's choosing (webhooks, read access, ...)."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient
from redline.server.app import create_app
from redline.server.core.config import Settings
from redline.server.db import migrate, session_factory
from redline.server.services.tokens import issue_token
from sqlalchemy import text

from tests.conftest import Services
from tests.test_api import SCOPES, Api
from tests.test_ingest import TABLES

_MIGRATED: set[str] = set()


@contextmanager
def api_with(services: Services, tmp_path: Path, **settings: Any) -> Iterator[Api]:
    """An app on an emptied, migrated database with one token per scope (named after it)."""
    if services.database_url not in _MIGRATED:
        migrate(services.database_url)
        _MIGRATED.add(services.database_url)
    config = Settings(
        database_url=services.database_url,
        redis_url=services.redis_url,
        storage_dir=tmp_path / "storage",
        queue=f"test-{uuid.uuid4().hex[:8]}",
        **settings,
    )
    with session_factory(config.database_url)() as session:
        session.execute(text(f"TRUNCATE {TABLES} RESTART IDENTITY CASCADE"))
        session.commit()
        tokens = {
            scope: {"Authorization": f"Bearer {issue_token(session, scope, scope)[1]}"}
            for scope in SCOPES
        }
    with TestClient(create_app(config)) as client:
        yield Api(client, config, tokens)
