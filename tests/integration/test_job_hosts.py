"""Only the host holding a job may fail it or upload its recording; a host-bound token acts for
its own host only (real Postgres and Redis, through the app)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from redline.server.db import session_factory
from redline.server.models import Job, JobState

from tests.support.api import Api, api_with, commit_of, expire_lease, recording_for
from tests.support.servers import Services


@pytest.fixture
def api(services: Services, tmp_path: Path) -> Iterator[Api]:
    with api_with(services, tmp_path, lease_seconds=60, max_attempts=3) as api:
        for name in ("perf1", "perf2"):
            api.post("/api/v1/agent/register", "agent", {"name": name}).raise_for_status()
        api.component()
        api.revision("r1", "1")
        yield api


def _fail(api: Api, job_id: int, host: str, scope: str = "agent") -> object:
    return api.post(f"/api/v1/jobs/{job_id}/fail", scope, {"host": host, "reason": "broke"})


def test_a_host_not_holding_the_job_can_neither_fail_nor_upload_it(api: Api, tmp_path: Path):
    job = api.lease("perf1")
    data = recording_for(job, tmp_path / "r1.mcap")
    failed = _fail(api, job["id"], "perf2")
    assert failed.status_code == 409 and "perf2" in failed.json()["detail"]
    uploaded = api.upload(job["id"], data, host="perf2")
    assert uploaded.status_code == 409 and "perf2" in uploaded.json()["detail"]
    assert api.job(job["id"])["state"] == "leased"
    assert api.upload(job["id"], data).status_code == 201  # perf1 holds it
    assert api.upload(job["id"], data).status_code == 200  # its resend is idempotent
    assert api.upload(job["id"], data, host="perf2").status_code == 409
    assert _fail(api, job["id"], "perf1").status_code == 409  # uploaded: no longer held


def test_a_lapsed_host_cannot_fail_or_upload_a_job_re_leased_to_another(api: Api, tmp_path: Path):
    job = api.lease("perf1")
    data = recording_for(job, tmp_path / "r1.mcap")
    expire_lease(api, job["id"])
    assert api.lease("perf2")["id"] == job["id"]
    assert _fail(api, job["id"], "perf1").status_code == 409
    assert api.upload(job["id"], data, host="perf1").status_code == 409
    assert api.job(job["id"])["state"] == "leased"
    assert _fail(api, job["id"], "perf2").json()["state"] == "failed"
    assert _fail(api, job["id"], "perf2").status_code == 200  # failing again changes nothing


def test_a_token_bound_to_one_host_cannot_fail_or_upload_for_another(api: Api, tmp_path: Path):
    made = api.post(
        "/api/v1/tokens", "admin", {"name": "perf1-token", "scopes": ["agent"], "host": "perf1"}
    )
    assert made.status_code == 201, made.text
    api.tokens["perf1-token"] = {"Authorization": f"Bearer {made.json()['token']}"}
    job = api.lease("perf2")
    data = recording_for(job, tmp_path / "r1.mcap")
    for answer in (
        _fail(api, job["id"], "perf2", scope="perf1-token"),
        api.upload(job["id"], data, host="perf2", scope="perf1-token"),
    ):
        assert answer.status_code == 403, answer.text
        assert "perf1" in answer.json()["detail"] and "perf2" in answer.json()["detail"]
    assert api.job(job["id"])["state"] == "leased"


def test_an_upload_must_name_its_host(api: Api, tmp_path: Path):
    job = api.lease("perf1")
    data = recording_for(job, tmp_path / "r1.mcap")
    answer = api.client.put(
        f"/api/v1/jobs/{job['id']}/recording",
        content=data,
        headers={**api.tokens["agent"], "X-Redline-Sha256": "0" * 64},
    )
    assert answer.status_code == 422 and "x-redline-host" in answer.text.lower()


def test_cancelling_a_revision_stops_its_jobs_and_its_agent_learns_at_the_next_heartbeat(api: Api):
    api.component("cancellable", executions=2)
    created = api.revision("c1", "1", component="cancellable")
    running = api.lease()  # newest revision first: one of c1's two jobs
    assert running["id"] in created["job_ids"]
    cancel = "/api/v1/components/cancellable/revisions/c1/cancel"
    assert api.post(cancel, "agent", {}).status_code == 403  # an agent token may not cancel
    answer = api.post(cancel, "ci", {})
    assert answer.status_code == 200, answer.text
    assert {job["state"] for job in answer.json()["jobs"]} == {"cancelled"}
    assert answer.json()["state"] == "cancelled"
    verdict = api.client.get("/api/v1/components/cancellable/revisions/c1/verdict").json()
    jobs = ", ".join(str(job_id) for job_id in created["job_ids"])
    assert verdict["reason"] == f"jobs {jobs} cancelled"  # not "cancelled: cancelled" (a trial)
    assert api.lease()["id"] not in created["job_ids"]  # c1's queued job is not handed out
    beat = api.post(f"/api/v1/jobs/{running['id']}/heartbeat", "agent", {"host": "perf1"})
    assert beat.status_code == 409
    missing = api.post("/api/v1/components/cancellable/revisions/nope/cancel", "ci", {})
    assert missing.status_code == 404 and "nope" in missing.json()["detail"]

    # reported again (the pipeline re-run): measured again, not left cancelled (a trial)
    body = {"component": "cancellable", "title": "c1", "sort_key": "1", "commit": commit_of("c1")}
    again = api.post("/api/v1/revisions", "ci", body)
    assert again.status_code == 200, again.text  # reported before
    assert sorted(again.json()["job_ids"]) == sorted(created["job_ids"])
    detail = api.client.get("/api/v1/components/cancellable/revisions/c1").json()
    assert {job["state"] for job in detail["jobs"]} == {"queued"}, detail["jobs"]
    verdict = api.client.get("/api/v1/components/cancellable/revisions/c1/verdict").json()
    assert verdict["state"] == "pending", verdict


def test_a_verdict_waiting_for_a_host_says_when_none_could_take_its_jobs(
    services: Services, tmp_path: Path
) -> None:
    """A trial's jobs needed the label 'nowhere': the verdict, the page and `ci wait` said only
    "waiting for a performance host to take its jobs"."""
    with api_with(services, tmp_path) as api:
        api.component("labelled", host_labels=["gpu", "quiet"])
        api.revision("r1", "1", component="labelled")

        def waiting() -> str:
            verdict = api.client.get("/api/v1/components/labelled/revisions/r1/verdict").json()
            assert verdict["state"] == "pending", verdict
            return verdict["waiting_for"]

        assert "no performance host has registered yet" in waiting()
        api.post("/api/v1/agent/register", "agent", {"name": "perf1", "labels": ["quiet"]})
        assert "no registered host has the label(s) 'gpu', 'quiet' they need" in waiting()
        api.post("/api/v1/agent/register", "agent", {"name": "perf2", "labels": ["quiet", "gpu"]})
        assert waiting() == "a performance host to take its jobs"  # perf2 may take them


def test_a_fault_of_the_commit_itself_runs_none_of_its_other_executions(api: Api):
    """A trial's broken suite failed its three executions one after another (41 s of the CI
    run's wait), each with the same words. An agent that says the fault is the commit's own
    (its suite file, its build) has the revision's queued executions cancelled, saying why; one
    another host runs already runs on; a failed run does not cancel the rest."""
    api.post("/api/v1/components/builder/revisions/r1/cancel", "ci", {}).raise_for_status()
    api.component("broken", executions=3)
    created = api.revision("b1", "1", component="broken")
    first, second = api.lease("perf1"), api.lease("perf2")
    assert {first["id"], second["id"]} <= set(created["job_ids"])
    reason = "build command 'make' exited with 2:\nMakefile:3: *** missing separator."
    failed = api.post(
        f"/api/v1/jobs/{first['id']}/fail",
        "agent",
        {"host": "perf1", "reason": reason, "of_commit": True},
    )
    assert failed.status_code == 200, failed.text
    jobs = {
        j["id"]: j for j in api.client.get("/api/v1/components/broken/revisions/b1").json()["jobs"]
    }
    (third,) = set(created["job_ids"]) - {first["id"], second["id"]}
    assert (jobs[third]["state"], jobs[third]["reason"]) == (
        "cancelled",
        f"not run: job {first['id']} of this commit failed so (build command 'make' exited "
        "with 2:)",
    )
    assert jobs[second["id"]]["state"] == "leased"  # perf2 runs it on, and may fail alike
    assert api.lease("perf1") is None  # nothing of it left to run
    # a run that failed says nothing of the others: they run
    created = api.revision("b2", "2", component="broken")
    run = api.lease("perf1")
    api.post(
        f"/api/v1/jobs/{run['id']}/fail", "agent", {"host": "perf1", "reason": "RuntimeError: x"}
    ).raise_for_status()
    jobs = api.client.get("/api/v1/components/broken/revisions/b2").json()["jobs"]
    assert sorted(j["state"] for j in jobs) == ["failed", "queued", "queued"]


def test_a_components_new_host_labels_apply_to_the_jobs_it_has_waiting(
    services: Services, tmp_path: Path
) -> None:
    """A trial set a component's host_labels to a label no host had, reported a commit, then
    set them back to []: its job kept the label it was queued with, no host took it, and
    `ci wait` waited until its timeout. The labels a component asks for now apply to every job
    of it not yet run; a host that holds one keeps it until its lease ends, and should the
    lease lapse, a host with the new labels takes it."""
    with api_with(services, tmp_path) as api:
        api.component("relabelled", host_labels=["mine"])
        created = api.revision("r1", "1", component="relabelled")
        assert created["warning"] == ""  # no host registered yet: one may be starting
        api.post("/api/v1/agent/register", "agent", {"name": "perf1", "labels": []})
        assert api.lease("perf1") is None
        # the report says so at once (the trial's `ci report` said nothing; `ci wait` did)
        second = api.revision("r0", "0", component="relabelled")
        said = "no registered host has the label(s) 'mine' relabelled's jobs need"
        assert said in second["warning"], second

        def labels(host_labels: list[str]) -> None:
            answer = api.client.patch(
                "/api/v1/components/relabelled",
                json={"host_labels": host_labels},
                headers=api.headers("admin"),
            )
            assert answer.status_code == 200, answer.text

        labels([])
        leased = api.lease("perf1")
        assert leased is not None and leased["id"] in created["job_ids"] + second["job_ids"]
        labels(["elsewhere"])
        with session_factory(api.settings.database_url)() as session:
            job = session.get_one(Job, leased["id"])
            assert (job.state, job.host.name, job.labels) == (
                JobState.leased,
                "perf1",
                ["elsewhere"],
            )
