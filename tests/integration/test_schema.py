"""The models and the migrations describe one schema: Alembic's autogenerate finds nothing to do
after migrating a fresh database to the newest revision (real Postgres)."""

from __future__ import annotations

from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from redline.server.db import get_engine, migrate
from redline.server.models import Base

from tests.support.servers import Services, fresh_database


def test_autogenerate_finds_the_models_and_the_migrated_schema_equal(services: Services):
    database_url, _ = fresh_database(services.database_url)
    migrate(database_url)
    with get_engine(database_url).connect() as connection:
        differences = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    assert differences == []
