"""Redline behind a real PgBouncer in transaction mode (issue 16; docs/operations.md): with
``REDLINE_DB_PGBOUNCER`` set, the API and the worker's ingestion, detection and re-analysis work
through it, clients taking turns on fewer server connections than there are clients (with the
setting off, the same test fails: ``prepared statement "_pg3_5" does not exist``). The control
shows that this PgBouncer does break what the setting turns off: psycopg's prepared statements,
which a server connection keeps while the next client's transaction runs on it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest
from redline.server.core.config import get_settings
from redline.server.db import session_factory
from redline.server.models import Component
from redline.worker.detection import detect_revision
from redline.worker.ingest import ingest_execution
from redline.worker.reanalysis import reanalyze_component
from sqlalchemy import select

from tests.support.api import Api, api_with, recording_for
from tests.support.pgbouncer import pgbouncer
from tests.support.servers import Services, fresh_database


@pytest.fixture
def bounced(services: Services, monkeypatch: pytest.MonkeyPatch) -> Iterator[Services]:
    """The test's services with the database reached through PgBouncer, and the setting on."""
    database_url, _ = fresh_database(services.database_url)
    with pgbouncer(database_url, pool_size=2) as url:
        monkeypatch.setenv("REDLINE_DB_PGBOUNCER", "true")
        get_settings.cache_clear()
        try:
            yield Services(url, services.redis_url)
        finally:
            get_settings.cache_clear()


def _verdicts(api: Api) -> list[tuple]:
    changes = api.client.get("/api/v1/components/builder/changes").json()
    return sorted(
        (c["revision"], c["series"]["counter"], c["method"], c["flagged"], c["score"])
        for c in changes
    )


def test_the_api_and_the_worker_work_through_pgbouncer_in_transaction_mode(
    bounced: Services, tmp_path: Path
):
    assert get_settings().db_pgbouncer
    with api_with(bounced, tmp_path) as api:  # migrated and tokens issued through it, too
        api.component()
        api.post("/api/v1/agent/register", "agent", {"name": "perf1"}).raise_for_status()
        for number, cpu in enumerate((20.0, 20.0, 20.0, 20.0, 60.0), start=1):
            api.revision(f"r{number}", str(number))
            job = api.lease()  # SELECT ... FOR UPDATE SKIP LOCKED
            assert job is not None
            data = recording_for(job, tmp_path / f"r{number}.mcap", cpu=cpu, seed=number)
            answer = api.upload(job["id"], data)
            assert answer.status_code == 201, answer.text
            for revision_id in ingest_execution(
                bounced.database_url, answer.json()["execution_id"]
            ):
                detect_revision(bounced.database_url, revision_id)  # advisory transaction lock
        first = _verdicts(api)
        flagged = [v[:3] for v in first if v[3]]
        assert ("r5", "cpu", "ks") in flagged and not [v for v in flagged if v[0] != "r5"]

        with session_factory(bounced.database_url)() as session:
            component_id = session.scalar(select(Component.id).where(Component.name == "builder"))
        # the walk and its writer thread: two transactions at once, on the 2 server connections
        assert reanalyze_component(bounced.database_url, component_id) == 5
        assert _verdicts(api) == first
        for page in ("/", "/components/builder", "/components/builder/revisions/r5"):
            assert api.client.get(page).status_code == 200, page


def _two_clients_take_turns(url: str, **options: object) -> None:
    """Two clients run the same statement ten times each, in turns, a transaction each time."""
    plain = url.replace("postgresql+psycopg://", "postgresql://", 1)
    with (
        psycopg.connect(plain, autocommit=True, **options) as one,
        psycopg.connect(plain, autocommit=True, **options) as other,
    ):
        for _ in range(10):
            for client in (one, other):
                with client.transaction():
                    client.execute("SELECT %s::int + 1", (1,))


def test_control_this_pgbouncer_breaks_psycopgs_prepared_statements(services: Services):
    """Two clients on one server connection, each preparing the statement it runs most (as
    psycopg does after five uses): the second one's name is taken by the first's. Without
    prepared statements (what ``REDLINE_DB_PGBOUNCER`` sets), the same turns work."""
    database_url, _ = fresh_database(services.database_url)
    with pgbouncer(database_url, pool_size=1) as url:
        with pytest.raises(psycopg.errors.DuplicatePreparedStatement):
            _two_clients_take_turns(url)
        _two_clients_take_turns(url, prepare_threshold=None)
