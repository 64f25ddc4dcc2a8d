"""Deleting a component, on real Postgres: its whole history and its files go, another
component's stay, nothing is deleted while one of its jobs is in flight, and only an admin may.

Two new users' trials registered a component by mistake, and it could not be removed (405)."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from redline.server.db import session_factory
from redline.server.models import (
    Alert,
    AlertedChange,
    Base,
    Component,
    Delivery,
    Detection,
    Execution,
    Job,
    JobState,
    Regression,
    ResourceModelRow,
    Revision,
    Series,
    Subscription,
    Summary,
    utcnow,
)
from redline.server.schemas.components import ComponentCreate
from redline.server.services.components import create_component
from redline.server.storage import samples_path
from redline.worker.alerts import scan_component
from sqlalchemy import func, select, update

from tests.support.api import Api, api_with
from tests.support.history import add_execution, cpu_history, ingest_and_detect
from tests.support.servers import Services


@pytest.fixture
def api(services: Services, tmp_path: Path):
    with api_with(services, tmp_path) as api:
        yield api


def _histories(api: Api, tmp_path: Path) -> list[str]:
    """'builder' with a regression at r7, 'other' with three revisions; the recordings'
    paths."""
    url = api.settings.database_url
    with session_factory(url)() as session:
        executions = cpu_history(session, tmp_path, [10.0] * 6 + [30.0])
        create_component(session, ComponentCreate(name="other"))
        rng = np.random.default_rng(3)
        others = [
            add_execution(
                session, tmp_path, "other", f"o{n}", str(n), {"cpu": rng.normal(5, 1, 60)}
            )
            for n in (1, 2, 3)
        ]
        paths = [execution.recording_path for execution in executions]
    ingest_and_detect(url, executions)
    ingest_and_detect(url, others)
    return paths


def _rows(api: Api) -> dict[str, int]:
    """Every table's row count."""
    with session_factory(api.settings.database_url)() as session:
        return {
            table.name: session.scalar(select(func.count()).select_from(table)) or 0
            for table in Base.metadata.sorted_tables
        }


def _count(session, model: type, where: object) -> int:
    return session.scalar(select(func.count()).select_from(model).where(where)) or 0


def test_deleting_a_component_removes_its_history_and_files_and_keeps_the_others(
    api: Api, tmp_path: Path
) -> None:
    paths = _histories(api, tmp_path)
    # subscribed (before its history) to every component and to this one: alerts about it
    webhook = {"kind": "webhook", "url": "http://127.0.0.1:9/hook", "confirmed_only": False}
    for path in ("/api/v1/subscriptions", "/api/v1/components/builder/subscriptions"):
        assert api.post(path, "admin", webhook).status_code == 201
    with session_factory(api.settings.database_url)() as session:
        session.execute(update(Subscription).values(created=utcnow() - timedelta(days=1)))
        builder = session.scalar(select(Component.id).where(Component.name == "builder"))
        assert len(scan_component(session, builder)) == 2
        session.commit()
        assert session.scalar(select(func.count()).select_from(Regression)) == 1
        assert _count(session, AlertedChange, AlertedChange.revision_id.is_not(None)) == 2
        other = session.scalar(select(Component.id).where(Component.name == "other"))
        kept = {
            "revision": _count(session, Revision, Revision.component_id == other),
            "series": _count(session, Series, Series.component_id == other),
            "execution": session.scalar(
                select(func.count())
                .select_from(Execution)
                .join(Revision, Revision.id == Execution.revision_id)
                .where(Revision.component_id == other)
            ),
        }
        # one file named by an execution of each (stored by content, the same bytes are one
        # file): it stays, with its sample table, for the component that keeps it
        shared = paths[0]
        first_of_other = session.scalar(
            select(func.min(Execution.id))
            .join(Revision, Revision.id == Execution.revision_id)
            .where(Revision.component_id == other)
        )
        session.execute(
            update(Execution).where(Execution.id == first_of_other).values(recording_path=shared)
        )
        session.commit()
    assert all(Path(path).exists() and samples_path(path).exists() for path in paths)
    assert (
        api.client.delete("/api/v1/components/builder", headers=api.tokens["ci"]).status_code == 403
    )
    answer = api.client.delete("/api/v1/components/builder", headers=api.tokens["admin"])
    assert answer.status_code == 200, answer.text
    assert answer.json() == {
        "deleted": "builder",
        "revisions": 7,
        "executions": 7,
        "regressions": 1,
        "files": 12,  # each execution's recording and sample table, but the shared one's
        "tokens_revoked": 0,  # none was bound to it
    }
    assert not any(Path(path).exists() or samples_path(path).exists() for path in paths[1:])
    assert Path(shared).exists() and samples_path(shared).exists()
    assert api.client.get("/api/v1/components/builder").status_code == 404
    with session_factory(api.settings.database_url)() as session:
        assert session.scalars(select(Component.name)).all() == ["other"]
        for model in (Revision, Series, Execution, Summary, Detection, Job):
            left = session.scalar(select(func.count()).select_from(model)) or 0
            assert left == kept.get(model.__tablename__, left) and left > 0, model.__tablename__
        assert session.scalar(select(func.count()).select_from(Regression)) == 0
        for model in (Alert, AlertedChange, Delivery):  # its own subscription's went with it
            assert session.scalar(select(func.count()).select_from(model)) == 0, model
        assert session.scalar(select(func.count()).select_from(Subscription)) == 1  # the global
    # the name is free again, for a component that starts with nothing
    made = api.post("/api/v1/components", "admin", {"name": "builder"})
    assert (
        made.status_code == 201
        and api.client.get("/api/v1/components/builder/revisions").json() == []
    )
    assert (
        api.client.delete("/api/v1/components/nosuch", headers=api.tokens["admin"]).status_code
        == 404
    )


def test_a_component_with_a_job_in_flight_is_not_deleted(api: Api, tmp_path: Path) -> None:
    _histories(api, tmp_path)
    before = _rows(api)
    with session_factory(api.settings.database_url)() as session:
        first = session.scalar(
            select(Job.id)
            .join(Revision, Revision.id == Job.revision_id)
            .join(Component, Component.id == Revision.component_id)
            .where(Component.name == "builder")
        )
        session.execute(update(Job).where(Job.id == first).values(state=JobState.running))
        session.commit()
    answer = api.client.delete("/api/v1/components/builder", headers=api.tokens["admin"])
    assert answer.status_code == 409, answer.text
    assert "1 job(s) held by a host or waiting to be ingested" in answer.json()["detail"]
    assert _rows(api) == before


def test_a_component_whose_model_is_being_trained_is_not_deleted(api: Api, tmp_path: Path) -> None:
    """A review: a training under way writes its model file after the delete; the row gone, the
    file would be left with no row naming it."""
    _histories(api, tmp_path)
    with session_factory(api.settings.database_url)() as session:
        builder = session.scalar(select(Component.id).where(Component.name == "builder"))
        session.add(ResourceModelRow(component_id=builder, state="running"))
        session.commit()
    before = _rows(api)
    answer = api.client.delete("/api/v1/components/builder", headers=api.tokens["admin"])
    assert answer.status_code == 409 and "a model's training under way" in answer.text
    assert _rows(api) == before


def test_a_revision_of_which_nothing_was_measured_is_deleted_and_one_with_results_stays(
    api: Api, tmp_path: Path
) -> None:
    """A new-user trial reported a commit that does not exist: its checkout failed, and the
    revision stayed "failed" on the home page for good, with no way to remove it."""
    _histories(api, tmp_path)
    mistake = api.revision("r-typo", "8", component="builder")
    for job_id in mistake["job_ids"]:  # as the agent reports a commit it cannot check out
        with session_factory(api.settings.database_url)() as session:
            job = session.get_one(Job, job_id)
            job.state, job.reason = JobState.failed, "checkout failed: commit deadbeef not found"
            session.commit()
    before = _rows(api)
    path = "/api/v1/components/builder/revisions/r-typo"
    for scope in ("ci", "triage", "read"):  # only an admin deletes
        assert api.client.delete(path, headers=api.tokens[scope]).status_code == 403, scope
    answer = api.client.delete(path, headers=api.tokens["admin"])
    assert answer.status_code == 200, answer.text
    jobs = len(mistake["job_ids"])
    assert answer.json() == {"deleted": "r-typo", "component": "builder", "jobs": jobs}
    after = _rows(api)
    assert (before["revision"] - after["revision"], before["job"] - after["job"]) == (1, jobs)
    assert {t: n for t, n in after.items() if t not in ("revision", "job")} == {
        t: n for t, n in before.items() if t not in ("revision", "job")
    }
    listed = api.client.get("/api/v1/components/builder/revisions").json()
    assert "r-typo" not in {revision["title"] for revision in listed}
    assert api.client.delete(path, headers=api.tokens["admin"]).status_code == 404
    # one with results stays, saying why; so does one a host holds a job of
    measured = api.client.delete(
        "/api/v1/components/builder/revisions/r7", headers=api.tokens["admin"]
    )
    assert measured.status_code == 409 and "1 execution(s) stored" in measured.text
    held = api.revision("r-held", "9", component="builder")
    with session_factory(api.settings.database_url)() as session:
        session.get_one(Job, held["job_ids"][0]).state = JobState.running
        session.commit()
    answer = api.client.delete(
        "/api/v1/components/builder/revisions/r-held", headers=api.tokens["admin"]
    )
    assert answer.status_code == 409 and "cancel it" in answer.text
    assert _rows(api)["revision"] == after["revision"] + 1
