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


def test_the_order_key_migration_reorders_what_the_old_keys_misordered(services: Services):
    """Migration 0016 rewrites stored order keys: Arabic-Indic three was ordered after five.
    (The schema at 0015 is the models' own: 0016 changes data only.)"""
    from alembic import command
    from redline.server.db import alembic_config, session_factory
    from redline.server.models import Revision
    from redline.server.schemas.components import ComponentCreate
    from redline.server.services.components import create_component
    from sqlalchemy import select

    database_url, _ = fresh_database(services.database_url)
    command.upgrade(alembic_config(database_url), "0015")
    order = select(Revision.title).order_by(Revision.order_key)
    with session_factory(database_url)() as session:
        component = create_component(session, ComponentCreate(name="c"))
        for title, sort_key, old in (("three", "\u0663", "01\u0663"), ("five", "5", "015")):
            session.add(
                Revision(
                    component_id=component.id,
                    title=title,
                    sort_key=sort_key,
                    order_key=old,
                    commit="main",
                )
            )
        session.commit()
        assert list(session.scalars(order)) == ["five", "three"]  # the old, wrong order
    migrate(database_url)
    with session_factory(database_url)() as session:
        assert list(session.scalars(order)) == ["three", "five"]
