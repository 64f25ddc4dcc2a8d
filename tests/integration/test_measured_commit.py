"""A revision is one commit: the hash its first uploaded run measured is pinned, every later job
of it (its own executions, the confirmation pairs that run it again) is leased that hash, and a
run that measured another commit is refused naming both (real Postgres and Redis, through the
app). An admin may report a revision by a branch's name; before this, a confirmation pair
queued later checked the branch out again, wherever it had moved."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from redline.server.db import session_factory
from redline.server.models import Host, Revision
from redline.worker.quiet_pairs import Scope, queue_pairs
from sqlalchemy import select

from tests.support.api import Api, api_with, commit_of, recording_for
from tests.support.servers import Services

FIRST, MOVED = commit_of("first"), commit_of("moved")


@pytest.fixture
def api(services: Services, tmp_path: Path) -> Iterator[Api]:
    with api_with(services, tmp_path, lease_seconds=60) as api:
        for name in ("perf1", "perf2"):
            api.post("/api/v1/agent/register", "agent", {"name": name}).raise_for_status()
        api.component(executions=2)
        yield api


def _revision(api: Api, title: str = "r1") -> dict:
    return api.client.get(f"/api/v1/components/builder/revisions/{title}").json()


def _pair_for(api: Api, title: str) -> None:
    """One confirmation pair of ``title`` against itself, as the worker queues them."""
    with session_factory(api.settings.database_url)() as session:
        revision = session.scalars(select(Revision).where(Revision.title == title)).one()
        host = session.scalars(select(Host).where(Host.name == "perf1")).one()
        queue_pairs(session, revision, revision.id, range(1, 2), host.id, Scope({}, True))
        session.commit()


def test_a_revision_named_by_a_branch_runs_again_at_the_hash_its_first_run_measured(
    api: Api, tmp_path: Path
) -> None:
    answer = api.post(
        "/api/v1/revisions",
        "admin",
        {"component": "builder", "title": "r1", "sort_key": "1", "commit": "main"},
    )
    assert answer.status_code == 201, answer.text
    first, second = api.lease("perf1"), api.lease("perf2")  # both before a run is uploaded
    assert first and second and first["commit"] == second["commit"] == "main"
    assert _revision(api)["measured_commit"] == ""

    data = recording_for(first, tmp_path / "a.mcap", commit_sha=FIRST)
    assert api.upload(first["id"], data, host="perf1").status_code == 201
    assert _revision(api)["measured_commit"] == FIRST

    # the branch moved before the second run checked it out: not this revision's commit
    data = recording_for(second, tmp_path / "b.mcap", commit_sha=MOVED)
    answer = api.upload(second["id"], data, host="perf2")
    assert answer.status_code == 400
    for said in (f"measured commit {MOVED[:12]}", f"measured {FIRST[:12]}", "one commit"):
        assert said in answer.json()["detail"], answer.text
    assert api.job(second["id"])["state"] == "failed"
    assert _revision(api)["measured_commit"] == FIRST  # nothing of the refused run kept

    _pair_for(api, "r1")  # as the worker queues a pair: both of its jobs leased the hash
    for _ in range(2):
        job = api.lease("perf1")
        assert job is not None and job["commit"] == FIRST
        data = recording_for(job, tmp_path / f"{job['id']}.mcap", commit_sha=FIRST)
        assert api.upload(job["id"], data, host="perf1").status_code == 201
    page = api.client.get("/components/builder/revisions/r1", headers=api.tokens["read"]).text
    assert "measured at <code" in page and FIRST[:12] in page


def test_a_run_of_a_hash_named_revision_that_measured_another_commit_is_refused(
    api: Api, tmp_path: Path
) -> None:
    cases = {"r1": (MOVED, f"commit_sha is '{MOVED}' but revision r1 is"), "r2": ("-x", "not a")}
    for sort_key, (title, (measured, said)) in enumerate(cases.items(), start=1):
        api.revision(title, str(sort_key))
        job = api.lease()
        assert job is not None and job["commit"] == commit_of(title)
        data = recording_for(job, tmp_path / f"{title}.mcap", commit_sha=measured)
        answer = api.upload(job["id"], data)
        assert answer.status_code == 400 and said in answer.json()["detail"], answer.text
        assert api.job(job["id"])["state"] == "failed"
        assert _revision(api, title)["measured_commit"] == ""
