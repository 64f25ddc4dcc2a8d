"""Engines, sessions and schema migration."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Any

from redline.server.core.config import PACKAGE, get_settings
from redline.server.models import Component
from sqlalchemy import Engine, NullPool, String, Table, create_engine, func, select, text
from sqlalchemy.orm import Session, sessionmaker

#: the first key of the transaction-scoped advisory lock one revision's detection holds
DETECT_LOCK = 0x5244  # "RD"


def lock_revision(session: Session, revision_id: int) -> None:
    """Detections of one revision take turns: a lock for the transaction."""
    session.execute(select(func.pg_advisory_xact_lock(DETECT_LOCK, revision_id)))


def lock_component(session: Session, component_id: int) -> None:
    """The component's row, locked for the transaction, before any of its jobs' rows: storing
    a revision's verdicts updates other revisions' and jobs' rows (`redline.worker.detection`),
    and so does a fresh run's ending (`redline.server.services.fresh_runs`); taking this lock
    first, they take turns and never deadlock."""
    session.execute(select(Component.id).where(Component.id == component_id).with_for_update())


def share_component(session: Session, component_id: int) -> None:
    """The component's row, key-share locked for the transaction: the lock a row that refers to
    it (a series, a delivery) takes when made, taken before the revision's row by whoever locks
    both. An import, and a commit status, locked the revision first and then waited for the
    component, which storing verdicts (`lock_component`, then the revision's row) held: a
    deadlock. Key-share locks do not wait for one another, only for `lock_component`'s."""
    session.execute(
        select(Component.id)
        .where(Component.id == component_id)
        .with_for_update(read=True, key_share=True)
    )


@lru_cache
def get_engine(database_url: str) -> Engine:
    """One engine per database URL in this process: a pool of at most ``REDLINE_DB_POOL_SIZE`` +
    ``REDLINE_DB_MAX_OVERFLOW`` connections; with ``REDLINE_DB_PGBOUNCER``, none of its own
    (PgBouncer pools) and no prepared statements (which its transaction mode cannot keep: psycopg
    prepares a statement on a connection after its fifth use). A statement's parameters are
    kept out of its errors (``hide_parameters``): an error writing a webhook secret, a
    subscription's or a commit status's would otherwise quote it into the traceback that the
    server logs."""
    settings = get_settings()
    if settings.db_pgbouncer:
        return create_engine(
            database_url,
            poolclass=NullPool,
            connect_args={"prepare_threshold": None},
            hide_parameters=True,
        )
    return create_engine(
        database_url,
        pool_pre_ping=True,
        pool_size=settings.db_pool_size,
        max_overflow=settings.db_max_overflow,
        pool_timeout=settings.db_pool_timeout_s,
        hide_parameters=True,
    )


def session_factory(database_url: str) -> sessionmaker[Session]:
    return sessionmaker(get_engine(database_url), expire_on_commit=False)


@contextmanager
def session_scope(database_url: str) -> Iterator[Session]:
    """A session whose transaction commits on success and rolls back on error."""
    with session_factory(database_url)() as session, session.begin():
        yield session


def bulk_insert(session: Session, table: Table, rows: Sequence[Mapping[str, Any]]) -> None:
    """Insert ``rows`` (dicts with the same keys, column names of ``table``) in one statement:
    ``INSERT ... SELECT * FROM unnest(one typed array per column)``. One round trip for hundreds
    of rows, where an executemany sends each row as a statement of its own."""
    if not rows:
        return
    columns = list(rows[0])
    dialect = session.get_bind().dialect

    def array_type(name: str) -> str:
        # strings as TEXT: a cast to VARCHAR(n) would cut an over-long value silently, where
        # the insert into the column itself refuses it
        kind = table.c[name].type
        return "TEXT" if isinstance(kind, String) else kind.compile(dialect=dialect)

    arrays = ", ".join(f"CAST(:{name} AS {array_type(name)}[])" for name in columns)
    session.execute(
        text(f"INSERT INTO {table.name} ({', '.join(columns)}) SELECT * FROM unnest({arrays})"),
        {name: [row[name] for row in rows] for name in columns},
    )


def alembic_config(database_url: str, migrations_dir: Path | None = None):  # noqa: ANN201
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(migrations_dir or PACKAGE / "migrations"))
    # '%' is configparser's interpolation character; URLs may carry percent-escapes
    config.set_main_option("sqlalchemy.url", database_url.replace("%", "%%"))
    return config


def migrate(database_url: str, migrations_dir: Path | None = None) -> None:
    """Upgrade the database at ``database_url`` to the newest schema (Alembic ``head``)."""
    from alembic import command

    command.upgrade(alembic_config(database_url, migrations_dir), "head")
