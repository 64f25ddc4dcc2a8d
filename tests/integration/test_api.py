"""The HTTP API through the real app, on real Postgres and Redis (the `services` fixture)."""

from __future__ import annotations

import hashlib
import html
import socket
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import redis
from fastapi.testclient import TestClient
from redline.server.app import create_app
from redline.server.core.config import Settings
from redline.server.core.security import hash_token
from redline.server.core.tasks import broker_url, queue_of
from redline.server.db import session_factory
from redline.server.models import ApiToken, Execution, Job, JobState
from redline.server.schemas.revisions import RevisionCreate
from redline.server.services.revisions import create_revision
from redline.worker.detection import detect_revision
from redline.worker.ingest import ingest_execution
from sqlalchemy import func, select, update

from tests.support.api import (
    Api,
    api_with,
    commit_of,
    emptied_with_tokens,
    expire_lease,
    recording_for,
)
from tests.support.pages import trend_data
from tests.support.servers import Services, live_server


@pytest.fixture
def api(services: Services, database_url: str, tmp_path: Path) -> Iterator[Api]:
    settings = Settings(
        database_url=database_url,
        redis_url=services.redis_url,
        storage_dir=tmp_path / "storage",
        queue=f"test-{uuid.uuid4().hex[:8]}",
        max_upload_bytes=2_000_000,
        max_unpacked_bytes=32 * 1024**2,
        lease_seconds=60,
        max_attempts=2,
    )
    tokens = emptied_with_tokens(database_url)
    with TestClient(create_app(settings)) as client:
        client.post(
            "/api/v1/agent/register",
            json={"name": "perf1", "labels": ["quiet"]},
            headers=tokens["agent"],
        ).raise_for_status()
        yield Api(client, settings, tokens)


def test_healthz_answers_without_a_token(api: Api):
    assert api.client.get("/healthz").json() == {"status": "ok", "database": "ok", "queue": "ok"}


def test_healthz_says_the_queue_is_away_and_uploads_are_still_taken(services, tmp_path):
    with socket.socket() as closed:  # a port nothing listens on
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    with api_with(services, tmp_path, redis_url=f"redis://127.0.0.1:{port}/0") as api:
        health = api.client.get("/healthz")
        assert health.status_code == 200, health.text
        assert health.json()["status"] == "degraded" and health.json()["database"] == "ok"
        assert health.json()["queue"].startswith("unavailable: "), health.json()
        assert str(port) in health.json()["queue"]


def test_missing_invalid_or_revoked_token_is_401(api: Api):
    body = {"name": "x"}
    assert api.client.post("/api/v1/components", json=body).status_code == 401
    bad = {"Authorization": "Bearer rl_not-a-token"}
    assert api.client.post("/api/v1/components", json=body, headers=bad).status_code == 401
    with session_factory(api.settings.database_url)() as session:
        session.execute(update(ApiToken).where(ApiToken.name == "admin").values(revoked=True))
        session.commit()
    assert api.post("/api/v1/components", "admin", body).status_code == 401


def test_wrong_scope_is_403_and_admin_implies_every_scope(api: Api):
    answer = api.post("/api/v1/components", "ci", {"name": "builder"})
    assert answer.status_code == 403 and "'admin'" in answer.json()["detail"]
    api.component()
    revision = {"component": "builder", "title": "r1", "sort_key": "1", "commit": "abc1234"}
    assert api.post("/api/v1/revisions", "agent", revision).status_code == 403
    assert api.post("/api/v1/agent/lease", "ci", {"host": "perf1"}).status_code == 403
    assert api.post("/api/v1/agent/lease", "read", {"host": "perf1"}).status_code == 403
    assert api.post("/api/v1/revisions", "admin", revision).status_code == 201


def test_unknown_component_is_404_naming_it(api: Api):
    answer = api.post(
        "/api/v1/revisions",
        "ci",
        {"component": "ghost", "title": "r1", "sort_key": "1", "commit": "abc1234"},
    )
    assert answer.status_code == 404 and "'ghost'" in answer.json()["detail"]
    for tail in ("revisions", "series", "changes", "revisions/r1"):
        answer = api.client.get(f"/api/v1/components/ghost/{tail}")
        assert answer.status_code == 404 and "ghost" in answer.json()["detail"]
    page = api.client.get("/components/ghost")
    assert page.status_code == 404 and "ghost" in page.text


def test_malformed_json_and_fields_are_422_naming_the_field(api: Api):
    answer = api.post("/api/v1/components", "admin", {"name": "builder", "executions": "many"})
    assert answer.status_code == 422
    assert [e["loc"][-1] for e in answer.json()["detail"]] == ["executions"]
    answer = api.post("/api/v1/revisions", "ci", {"component": "builder", "title": "r1"})
    assert answer.status_code == 422
    assert [e["loc"][-1] for e in answer.json()["detail"]] == ["sort_key", "commit"]
    # a commit is what the performance hosts check out: an empty one is refused here, not
    # by a job failing on a host (a trial from outside, 2026-11-24)
    empty = {"component": "builder", "title": "r1", "sort_key": "1", "commit": ""}
    answer = api.post("/api/v1/revisions", "ci", empty)
    assert answer.status_code == 422
    assert [e["loc"][-1] for e in answer.json()["detail"]] == ["commit"]
    broken = api.client.post(
        "/api/v1/components",
        content=b"{not json",
        headers={**api.tokens["admin"], "Content-Type": "application/json"},
    )
    assert broken.status_code == 422


def test_duplicate_component_or_revision_title_is_409(api: Api):
    api.component()
    assert api.post("/api/v1/components", "admin", {"name": "builder"}).status_code == 409
    api.revision("r1", "1")
    answer = api.post(
        "/api/v1/revisions",
        "ci",
        {"component": "builder", "title": "r1", "sort_key": "5", "commit": "def4567"},
    )
    assert answer.status_code == 409 and "'r1'" in answer.json()["detail"]
    assert repr(commit_of("r1")) in answer.json()["detail"]  # both commits named


def test_a_component_named_as_another_but_for_case_is_refused_and_a_lookup_suggests_it(
    api: Api,
):
    """A trial made 'hasher' and 'Hasher': two components, each with half of its history."""
    api.component()
    answer = api.post("/api/v1/components", "admin", {"name": "Builder"})
    assert answer.status_code == 409, answer.text
    assert "'builder' already exists" in answer.json()["detail"]
    answer = api.post(
        "/api/v1/revisions",
        "ci",
        {"component": "BUILDER", "title": "r1", "sort_key": "1", "commit": "abc1234"},
    )
    assert answer.status_code == 404
    assert answer.json()["detail"] == (
        "unknown component 'BUILDER' (names are case-sensitive: did you mean 'builder'?)"
    )
    assert "did you mean 'builder'" in html.unescape(api.client.get("/components/Builder").text)
    # a letter missing: a trial's 'planer' for 'planner' got no hint
    body = {"component": "bulder", "title": "r1", "sort_key": "1", "commit": "abc1234"}
    answer = api.post("/api/v1/revisions", "ci", body)
    assert answer.json()["detail"] == "unknown component 'bulder' (did you mean 'builder'?)"
    answer = api.post("/api/v1/revisions", "ci", {**body, "component": "hasher"})
    assert answer.json()["detail"] == "unknown component 'hasher'"  # nothing near it


def test_a_revision_reported_again_with_its_commit_is_the_same_revision(api: Api):
    """A re-run CI pipeline (or CI and a webhook both) report a revision again: ci.md's
    `curl -fsS` failed on the 409 before `redline ci wait` could run (a trial)."""
    api.component()
    body = {"component": "builder", "title": "r1", "sort_key": "7", "commit": "c" * 40}
    first = api.post("/api/v1/revisions", "ci", body)
    assert first.status_code == 201, first.text
    again = api.post("/api/v1/revisions", "ci", body)
    assert again.status_code == 200 and again.json() == first.json(), again.text
    # a webhook's key for the same commit ("7.0000") or a CI's: the first report's stands
    keyed = api.post("/api/v1/revisions", "ci", {**body, "sort_key": "7.0000"})
    assert keyed.status_code == 200 and keyed.json() == first.json(), keyed.text
    other = api.post("/api/v1/revisions", "ci", {**body, "commit": "d" * 40})
    assert other.status_code == 409 and "c" * 40 in other.json()["detail"], other.text
    listed = api.client.get("/api/v1/components/builder/revisions").json()
    assert [r["title"] for r in listed] == ["r1"] and len(first.json()["job_ids"]) >= 1


def test_a_commit_reported_under_its_full_and_its_short_sha_is_one_revision(api: Api):
    """README's example titled a revision by the full SHA, ci.md and the webhooks by 12 digits:
    a trial reporting both got 201 twice, and the commit measured twice."""
    api.component()
    full = "0123456789abcdef" * 2 + "01234567"
    body = {"component": "builder", "title": full, "sort_key": "7", "commit": full}
    first = api.post("/api/v1/revisions", "ci", body)
    assert first.status_code == 201, first.text
    for title, commit in ((full[:12], full), (full[:12], full[:12]), ("r7", full[:7].upper())):
        again = api.post("/api/v1/revisions", "ci", {**body, "title": title, "commit": commit})
        assert again.status_code == 200 and again.json() == first.json(), (title, again.text)
    # a six-digit prefix, or a branch name, is no commit's identity: a revision of its own (an
    # admin's report: a ci token's is refused, `test_a_ci_token_names_the_commit_it_reports_...`)
    for title, commit in (("short", full[:6]), ("nightly-1", "main"), ("nightly-2", "main")):
        made = api.post("/api/v1/revisions", "admin", {**body, "title": title, "commit": commit})
        assert made.status_code == 201, made.text
    listed = api.client.get("/api/v1/components/builder/revisions").json()
    assert sorted(r["title"] for r in listed) == sorted([full, "short", "nightly-1", "nightly-2"])
    with session_factory(api.settings.database_url)() as session:
        assert session.scalar(select(func.count()).select_from(Job)) == 4  # none for repeats


def test_a_revision_is_found_by_its_commit_hash_full_or_abbreviated(api: Api):
    """A trial's `ci wait --revision 2b2a811` (and with the full SHA) waited 2 minutes for a
    revision `ci report` had titled by 12 digits, and gave up "has no revision"."""
    api.component()
    full, other = "2b2a811aa80c" + "0" * 28, "2b2a811bb" + "1" * 31
    for title, commit, key in ((full[:12], full, "1"), ("v2", other, "2")):
        made = api.post(
            "/api/v1/revisions",
            "ci",
            {"component": "builder", "title": title, "commit": commit, "sort_key": key},
        )
        assert made.status_code == 201, made.text
    base = "/api/v1/components/builder/revisions/"
    for asked in (full, full[:9], full[:12].upper(), other[:12]):
        found = api.client.get(base + asked)
        assert found.status_code == 200, (asked, found.text)
        assert found.json()["title"] == ("v2" if asked == other[:12] else full[:12]), asked
        verdict = api.client.get(base + asked + "/verdict", headers=api.headers("ci"))
        assert verdict.status_code == 200 and verdict.json()["revision"] == found.json()["title"]
    page = api.client.get("/components/builder/revisions/" + full)
    assert page.status_code == 200 and full[:12] in page.text
    # seven digits both commits start with: which one is not guessed, both are named (a 400,
    # not "no revision", which `ci wait` would wait two minutes to see appear)
    both = api.client.get(base + full[:7])
    assert both.status_code == 400, both.text
    assert all(t in both.json()["detail"] for t in (full[:12], "'v2'", "give more of it"))
    assert "has no revision" not in both.json()["detail"]
    # one commit under two titles (reported before they were one revision): not "several"
    with session_factory(api.settings.database_url)() as session:
        for title, commit in (("t-short", "c0ffee1"), ("t-full", "c0ffee1" + "2" * 33)):
            create_revision(
                session,
                RevisionCreate(component="builder", title=title, commit=commit, sort_key="5"),
            )
    assert api.client.get(base + "c0ffee12").json()["title"] == "t-short"
    # what deletes, moves or cancels a revision names it by its title only
    admin, ci = api.headers("admin"), api.headers("ci")
    assert api.client.delete(base + full, headers=admin).status_code == 404
    moved = api.client.patch(base + full, json={"sort_key": "9"}, headers=admin)
    assert moved.status_code == 404
    assert api.client.post(base + full + "/cancel", headers=ci).status_code == 404
    # a hash of no commit, and a title that is no hash, are not found as before
    for asked in ("2b2a812", "nightly"):
        missing = api.client.get(base + asked)
        assert missing.status_code == 404
        assert missing.json()["detail"] == f"component 'builder' has no revision {asked!r}"


def test_a_failed_revision_says_it_failed_and_why_not_that_a_verdict_is_coming(api: Api):
    """A trial's revision whose every job failed read "No verdict yet ... has not been
    analysed", as if it were still coming, and its API verdict was ""."""
    api.component(executions=2)
    api.revision("r1", "1")
    with session_factory(api.settings.database_url)() as session:
        reasons = iter(("build failed: exit 2", "the host went away"))
        for job in session.scalars(select(Job)):
            job.state, job.reason = JobState.failed, next(reasons)
        session.commit()
    detail = api.client.get("/api/v1/components/builder/revisions/r1").json()
    assert detail["state"] == "failed"
    assert detail["verdict"] == (
        "no verdict: the revision failed, 2 of its 2 jobs "
        "(build failed: exit 2; the host went away)"
    )
    page = html.unescape(api.client.get("/components/builder/revisions/r1").text)
    assert detail["verdict"] in page and "not been analysed" not in page
    assert "No verdict yet" not in page
    # the component page's row too (a trial's failed first commit had an empty verdict cell)
    listed = html.unescape(api.client.get("/components/builder").text)
    assert detail["verdict"] in listed


def test_revisions_are_listed_in_sort_key_order_with_their_state(api: Api):
    api.component(executions=2)
    for title, key in (("ten", "10"), ("nine", "9"), ("two", "2")):
        created = api.revision(title, key)
        assert len(created["job_ids"]) == 2
    listed = api.client.get("/api/v1/components/builder/revisions").json()
    assert [r["title"] for r in listed] == ["two", "nine", "ten"]
    assert {r["state"] for r in listed} == {"queued"}
    detail = api.client.get("/api/v1/components/builder/revisions/nine").json()
    assert [(j["execution_index"], j["state"]) for j in detail["jobs"]] == [
        (0, "queued"),
        (1, "queued"),
    ]


def test_lease_hands_out_newest_revision_first_then_204(api: Api):
    api.component()
    first, second = api.revision("r9", "9"), api.revision("r10", "10")
    job = api.lease()
    assert job["id"] == second["job_ids"][0]
    assert job["revision"] == {"title": "r10", "sort_key": "10"}
    assert (job["component"], job["commit"], job["suite"]) == (
        "builder",
        commit_of("r10"),
        "perf/redline.toml",
    )
    assert api.lease()["id"] == first["job_ids"][0]
    assert api.lease() is None
    unknown = api.post("/api/v1/agent/lease", "agent", {"host": "stranger"})
    assert unknown.status_code == 404 and "stranger" in unknown.json()["detail"]


def test_a_busy_component_does_not_starve_the_others(api: Api):
    """Components take turns (served longest ago first), newest revision first within one: a
    component whose CI reports faster than the hosts run leaves room for the others."""
    api.component("quiet")
    api.component("busy")
    waiting = api.revision("q1", "1", component="quiet")["job_ids"][0]
    busy = [api.revision(f"b{n}", str(n), component="busy")["job_ids"][0] for n in (1, 2, 3)]
    assert api.lease()["id"] == busy[2]  # neither served yet: the newest report
    busy.append(api.revision("b4", "4", component="busy")["job_ids"][0])  # still reporting
    assert api.lease()["id"] == waiting
    assert [api.lease()["id"] for _ in range(3)] == [busy[3], busy[1], busy[0]]
    assert api.lease() is None


def test_lease_hands_a_host_only_jobs_of_pools_it_belongs_to(api: Api):
    api.component("plain")
    api.component("needs_gpu", host_labels=["gpu"])
    gpu_job = api.revision("g1", "1", component="needs_gpu")["job_ids"][0]
    plain_job = api.revision("p1", "1", component="plain")["job_ids"][0]
    assert api.lease()["id"] == plain_job  # perf1 has only the label "quiet"
    assert api.lease() is None
    api.post(
        "/api/v1/agent/register", "agent", {"name": "perf2", "labels": ["gpu", "quiet"]}
    ).raise_for_status()
    assert api.lease("perf2")["id"] == gpu_job


def test_an_agent_token_naming_its_host_acts_for_that_host_only(api: Api):
    made = api.post(
        "/api/v1/tokens", "admin", {"name": "perf1-token", "scopes": ["agent"], "host": "perf1"}
    )
    assert made.status_code == 201, made.text
    own = {"Authorization": f"Bearer {made.json()['token']}"}
    api.post("/api/v1/agent/register", "agent", {"name": "perf9", "labels": []}).raise_for_status()
    for path, body in (
        ("/api/v1/agent/register", {"name": "perf9", "labels": []}),
        ("/api/v1/agent/lease", {"host": "perf9"}),
        ("/api/v1/jobs/1/heartbeat", {"host": "perf9"}),
        ("/api/v1/jobs/1/release", {"host": "perf9"}),
    ):
        answer = api.client.post(path, json=body, headers=own)
        assert answer.status_code == 403, (path, answer.text)
        assert "perf1" in answer.json()["detail"] and "perf9" in answer.json()["detail"]
    assert (
        api.client.post("/api/v1/agent/lease", json={"host": "perf1"}, headers=own).status_code
        == 204
    )


def test_a_host_registers_only_with_the_labels_its_token_was_given(api: Api):
    """A component's host labels say which hosts run its jobs; a host naming its own labels
    leased any component's (a security review's find). Now an admin gives the token its labels
    and the host registers with those or fewer."""
    api.component("needs_gpu", host_labels=["gpu"])
    gpu_job = api.revision("g1", "1", component="needs_gpu")["job_ids"][0]
    made = api.post(
        "/api/v1/tokens",
        "admin",
        {"name": "team-box", "scopes": ["agent"], "host": "team1", "labels": ["x86", "quiet"]},
    )
    assert made.status_code == 201 and made.json()["labels"] == ["quiet", "x86"], made.text
    own = {"Authorization": f"Bearer {made.json()['token']}"}
    claimed = {"name": "team1", "labels": ["quiet", "gpu", "fast"]}
    refused = api.client.post("/api/v1/agent/register", json=claimed, headers=own)
    assert refused.status_code == 403, refused.text
    assert "with the labels quiet, x86, not fast, gpu" in refused.json()["detail"]
    assert "revoke this token and create one with --labels" in refused.json()["detail"]
    for labels in ([], ["quiet"], ["x86", "quiet"]):  # those it was given, or fewer
        body = {"name": "team1", "labels": labels}
        answer = api.client.post("/api/v1/agent/register", json=body, headers=own)
        assert answer.status_code == 200, answer.text
    leased = api.client.post("/api/v1/agent/lease", json={"host": "team1"}, headers=own)
    assert leased.status_code == 204  # the gpu component's job is not its to run
    # nor when the host's row says gpu (registered so under an admin's or a revoked token)
    widened = {"name": "team1", "labels": ["gpu"]}
    api.client.post("/api/v1/agent/register", json=widened, headers=api.tokens["admin"])
    leased = api.client.post("/api/v1/agent/lease", json={"host": "team1"}, headers=own)
    assert leased.status_code == 204, leased.text
    api.post("/api/v1/agent/register", "agent", {"name": "perf1", "labels": ["gpu"]})
    assert api.lease()["id"] == gpu_job
    listed = {
        t["name"]: t for t in api.client.get("/api/v1/tokens", headers=api.tokens["admin"]).json()
    }
    assert listed["team-box"]["labels"] == ["quiet", "x86"]
    # labels are an agent token's, and words
    body = {"name": "ci3", "scopes": ["ci"], "labels": ["gpu"]}
    answer = api.post("/api/v1/tokens", "admin", body)
    assert answer.status_code == 400 and "labels ['gpu'] are an agent token's" in answer.text
    body = {"name": "a3", "scopes": ["agent"], "host": "h3", "labels": ["two words"]}
    answer = api.post("/api/v1/tokens", "admin", body)
    assert answer.status_code == 422 and answer.json()["detail"][0]["loc"] == ["body", "labels", 0]


def test_an_agent_refused_its_labels_says_why_and_stops(api: Api, tmp_path: Path):
    """A refusal of its token is no passing outage: the agent says the server's reason and
    exits, rather than retry for good behind "Client error '403 Forbidden'"."""
    import os
    import subprocess
    import sys

    secret = api.tokens["agent"]["Authorization"].removeprefix("Bearer ")
    redline = str(Path(sys.executable).parent / "redline")
    with live_server(api.settings) as url:
        done = subprocess.run(
            [
                redline,
                "agent",
                "--server",
                url,
                "--name",
                "perf1",
                "--label",
                "root",
                "--work",
                str(tmp_path / "work"),
            ],  # fmt: skip
            env={**os.environ, "REDLINE_TOKEN": secret},
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert done.returncode == 1, done.stderr
    assert "the server refused to register 'perf1'" in done.stderr
    assert "labels gpu, quiet, not root" in done.stderr and secret not in done.stderr


def test_an_agent_token_must_be_bound_to_a_host(api: Api):
    """One that may act as any host is not issued; only an agent token has a host."""
    for body in ({"name": "any", "scopes": ["agent"]}, {"name": "any", "scopes": ["ci", "agent"]}):
        answer = api.post("/api/v1/tokens", "admin", body)
        assert answer.status_code == 400 and "--host" in answer.json()["detail"], answer.text
    stray = api.post("/api/v1/tokens", "admin", {"name": "ci2", "scopes": ["ci"], "host": "perf1"})
    assert stray.status_code == 400 and "'agent'" in stray.json()["detail"]
    with session_factory(api.settings.database_url)() as session:
        assert not session.scalar(select(ApiToken).where(ApiToken.name.in_(["any", "ci2"])))


def test_a_pool_token_acts_for_the_hosts_its_prefix_names(api: Api):
    """Replicas of one container (compose's `--scale agent=M`) share a token bound to
    'compose-*': each registers and leases as itself; none acts as a host named otherwise."""
    made = api.post(
        "/api/v1/tokens", "admin", {"name": "replicas", "scopes": ["agent"], "host": "compose-*"}
    )
    assert made.status_code == 201, made.text
    pool = {"Authorization": f"Bearer {made.json()['token']}"}
    for name in ("compose-3f2a", "compose-9c1b"):
        registered = api.client.post(
            "/api/v1/agent/register", json={"name": name, "labels": []}, headers=pool
        )
        assert registered.status_code == 200, registered.text
    for name in ("perf1", "compose-"):
        answer = api.client.post("/api/v1/agent/lease", json={"host": name}, headers=pool)
        assert answer.status_code == 403 and "'compose-*'" in answer.json()["detail"], answer.text
    alert = {"target": "cpu_percent", "started": True, "residual": 1.0, "threshold": 0.5}
    api.component()
    unnamed = api.client.post("/api/v1/components/builder/runtime-alerts", json=alert, headers=pool)
    assert unnamed.status_code == 403  # a pool's token must say which of its hosts reports
    for host in ("*", "perf-*-x"):
        body = {"name": f"bad{len(host)}", "scopes": ["agent"], "host": host}
        refused = api.post("/api/v1/tokens", "admin", body)
        assert refused.status_code == 400 and "alone would be any host" in refused.text
    # a CR/LF broke `redline token list`'s rows and the pages' host tables (a trial)
    for body, status, said in (
        ({"name": "bad", "scopes": ["agent"], "host": "perf\r\n3"}, 400, "'\\r' at position 4"),
        # a name is refused by the schema, as every name is (422 naming it)
        ({"name": "bad\r\nrow", "scopes": ["ci"]}, 422, "must not contain '\\r' at position 3"),
        # DELETE /tokens/perf%2F1 could not find it (a trial)
        ({"name": "perf/1", "scopes": ["ci"]}, 422, "must not contain '/'"),
    ):
        refused = api.post("/api/v1/tokens", "admin", body)
        detail = refused.json()["detail"]
        told = detail if isinstance(detail, str) else detail[0]["msg"]
        assert refused.status_code == status and said in told, refused.text
    for body in ({"name": "compose-\r\nX"}, {"name": "compose-x", "labels": ["l\r\n"]}):
        answer = api.client.post("/api/v1/agent/register", json=body, headers=pool)
        said = answer.json()["detail"][0]["msg"]
        assert answer.status_code == 422 and said.startswith("must not contain '\\r'"), said
    # a replica named itself out of the pool's one path segment (a trial)
    answer = api.client.post(
        "/api/v1/agent/register", json={"name": "compose-../../x"}, headers=pool
    )
    said = answer.json()["detail"][0]["msg"]
    assert answer.status_code == 422 and said.startswith("must not contain '/'"), said
    refused = api.post("/api/v1/tokens", "admin", {"name": "b", "scopes": ["agent"], "host": "a/b"})
    assert refused.status_code == 400 and "must not contain '/'" in refused.json()["detail"]


def test_an_agent_token_bound_to_no_host_acts_for_none(api: Api):
    """One issued before a host was required (made here as it was stored then) is refused
    everywhere an agent acts: it registers, leases and reports as no host."""
    with session_factory(api.settings.database_url)() as session:
        session.add(ApiToken(name="old", token_hash=hash_token("rl_old"), scopes=["agent"]))
        session.commit()
    old = {"Authorization": "Bearer rl_old"}
    alert = {"target": "cpu_percent", "started": True, "residual": 1.0, "threshold": 0.5}
    api.component()
    for path, body in (
        ("/api/v1/agent/register", {"name": "perf1", "labels": []}),
        ("/api/v1/agent/lease", {"host": "perf1"}),
        ("/api/v1/components/builder/runtime-alerts", alert),
    ):
        answer = api.client.post(path, json=body, headers=old)
        assert answer.status_code == 403, (path, answer.text)
        assert "bound to no host" in answer.json()["detail"]
    admin = api.client.post(
        "/api/v1/agent/register", json={"name": "perf9", "labels": []}, headers=api.tokens["admin"]
    )
    assert admin.status_code == 200, admin.text  # an admin token without a host acts for any


def test_lease_skips_a_job_another_transaction_has_locked(api: Api):
    api.component()
    first, second = api.revision("r1", "1"), api.revision("r2", "2")
    with session_factory(api.settings.database_url)() as other:
        other.scalar(select(Job).where(Job.id == second["job_ids"][0]).with_for_update())
        assert api.lease()["id"] == first["job_ids"][0]  # not blocked, not the locked one
        other.rollback()
    assert api.lease()["id"] == second["job_ids"][0]


def test_heartbeat_extends_the_lease_and_marks_the_job_running(api: Api):
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    for path, body in (  # a stray field is refused, never ignored (a trial's were taken)
        (f"/api/v1/jobs/{job['id']}/heartbeat", {"host": "perf1", "x": 1}),
        (f"/api/v1/jobs/{job['id']}/fail", {"host": "perf1", "reason": "r", "x": 1}),
    ):
        stray = api.post(path, "agent", body)
        assert stray.status_code == 422 and stray.json()["detail"][0]["loc"] == ["body", "x"]
    assert api.job(job["id"])["state"] == "leased"  # neither beat nor failed
    beat = api.post(f"/api/v1/jobs/{job['id']}/heartbeat", "agent", {"host": "perf1"})
    assert beat.status_code == 200
    assert beat.json()["lease_expires_at"] >= job["lease_expires_at"]
    assert api.job(job["id"])["state"] == "running"
    other = api.post(f"/api/v1/jobs/{job['id']}/heartbeat", "agent", {"host": "perf2"})
    assert other.status_code == 409


def test_lapsed_lease_goes_to_another_host_until_attempts_run_out(api: Api):
    api.component()
    api.revision("r1", "1")
    api.post("/api/v1/agent/register", "agent", {"name": "perf2"}).raise_for_status()
    job = api.lease("perf1")
    expire_lease(api, job["id"])
    again = api.lease("perf2")
    assert again["id"] == job["id"]
    late = api.post(f"/api/v1/jobs/{job['id']}/heartbeat", "agent", {"host": "perf1"})
    assert late.status_code == 409
    expire_lease(api, job["id"])  # second lapse: max_attempts (2) reached
    assert api.lease("perf1") is None
    failed = api.job(job["id"])
    assert failed["state"] == "failed" and "lease expired" in failed["reason"]


def test_fail_marks_the_job_and_revision_failed_with_the_reason(api: Api):
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    answer = api.post(
        f"/api/v1/jobs/{job['id']}/fail", "agent", {"host": "perf1", "reason": "build broke"}
    )
    assert answer.json() == {"id": job["id"], "state": "failed", "reason": "build broke"}
    listed = api.client.get("/api/v1/components/builder/revisions").json()
    assert listed[0]["state"] == "failed"


def test_valid_upload_stores_the_execution_and_queues_ingestion(api: Api, tmp_path: Path):
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    data = recording_for(job, tmp_path / "r1.mcap")
    answer = api.upload(job["id"], data)
    assert answer.status_code == 201, answer.text
    assert answer.json()["ingest_queued"] is True
    stored = api.job(job["id"])
    assert stored["state"] == "uploaded"
    assert stored["execution"]["sha256"] == hashlib.sha256(data).hexdigest()
    assert (
        api.settings.storage_dir / "recordings" / f"{stored['execution']['sha256']}.mcap"
    ).read_bytes() == data
    broker = redis.Redis.from_url(api.settings.redis_url)
    # the ingest task waits in the real broker, on the queue of ingestion
    assert broker.llen(queue_of(api.settings, "ingest")) == 1
    assert broker.llen(queue_of(api.settings, "detect")) == 0
    assert broker_url("unix:///tmp/r.sock") == "redis+socket:///tmp/r.sock"


def test_repeated_upload_is_idempotent(api: Api, tmp_path: Path):
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    data = recording_for(job, tmp_path / "r1.mcap")
    first, second = api.upload(job["id"], data), api.upload(job["id"], data)
    assert (first.status_code, second.status_code) == (201, 200)
    assert first.json()["execution_id"] == second.json()["execution_id"]
    other = recording_for(job, tmp_path / "other.mcap", seed=7)
    assert api.upload(job["id"], other).status_code == 409
    assert _executions(api) == 1


def test_an_upload_is_refused_for_its_hash_header_job_or_host_naming_no_other_hosts(
    api: Api, tmp_path: Path
):
    """A trial's 200 MB were read, then refused for their hash, for a job that did not exist;
    a 409 named the sha256 of another host's recording. (That these refusals come before the
    body is read is the route's order, `check_before_reading` first; the test client sends the
    body whole, so this test does not see it.)"""
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    data = recording_for(job, tmp_path / "r1.mcap")
    bad = api.upload(job["id"], data, sha256="zz")
    assert bad.status_code == 422 and "'zz' is not a sha256" in bad.text
    unknown = api.upload(99999, data)
    assert unknown.status_code == 404 and "unknown job 99999" in unknown.text
    other = api.upload(job["id"], data, host="perf9")
    assert other.status_code == 409 and other.json()["detail"] == (
        f"job {job['id']} is not held by host 'perf9'"
    )
    assert api.upload(job["id"], data).status_code == 201
    stranger = api.upload(job["id"], recording_for(job, tmp_path / "x.mcap", seed=3), host="perf9")
    assert stranger.status_code == 409 and "sha256" not in stranger.text  # nothing of perf1's
    assert _executions(api) == 1 and api.job(job["id"])["state"] == "uploaded"
    # a job that takes no recording any more is said so before the body is read, not after it
    # as a hash that does not match ("send it again", a trial was told of a failed job)
    other = recording_for(job, tmp_path / "y.mcap", seed=4)
    again = api.upload(job["id"], other, sha256="0" * 64)
    assert again.status_code == 409 and "already has a different recording" in again.text
    api.revision("r2", "2")
    failed = api.lease()
    gave_up = api.post(
        f"/api/v1/jobs/{failed['id']}/fail", "agent", {"host": "perf1", "reason": "x"}
    )
    assert gave_up.status_code == 200, gave_up.text
    late = api.upload(failed["id"], data, sha256="0" * 64)
    assert late.status_code == 409, late.text
    assert f"job {failed['id']} is not leased to host 'perf1' (state failed" in late.text
    assert _executions(api) == 1


def _executions(api: Api) -> int:
    with session_factory(api.settings.database_url)() as session:
        return session.scalar(select(func.count()).select_from(Execution))


def _assert_refused(api: Api, job_id: int, data: bytes, words: str) -> None:
    answer = api.upload(job_id, data)
    assert answer.status_code == 400, answer.text
    assert words in answer.json()["detail"]
    stored = api.job(job_id)
    assert stored["state"] == "failed" and words in stored["reason"]
    assert stored["execution"] is None and _executions(api) == 0
    assert not list((api.settings.storage_dir / "incoming").iterdir())
    assert not (api.settings.storage_dir / "recordings").exists()


def test_truncated_upload_is_refused_and_fails_the_job(api: Api, tmp_path: Path):
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    data = recording_for(job, tmp_path / "r1.mcap")
    _assert_refused(api, job["id"], data[: len(data) * 2 // 3], "truncated")


def test_non_mcap_upload_is_refused_and_fails_the_job(api: Api):
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    _assert_refused(
        api, job["id"], b"PK\x03\x04 this is a zip, not a recording" * 20, "not an MCAP file"
    )


def test_an_upload_that_unpacks_beyond_the_limit_is_refused_naming_the_setting(
    api: Api, tmp_path: Path
):
    """A few kilobytes of upload that unpack to gigabytes held the server's memory (any host
    holding a job may send one): here 40 MiB of zeros in a file of a few KiB."""
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    data = recording_for(job, tmp_path / "r1.mcap", extra=("robot/scan", bytes(40 * 1024**2)))
    assert len(data) < 100_000
    _assert_refused(api, job["id"], data, "upload unpacks to more than 32 MiB, the server's limit")
    assert "REDLINE_MAX_UNPACKED_BYTES" in api.job(job["id"])["reason"]


@pytest.mark.parametrize(
    ("topic", "data", "words"),
    [  # what a hostile-input probe uploaded: accepted, then ingestion failed with a KeyError
        # or TypeError and left the job "uploaded" for good; a 500 for the nesting
        ("@redline/counters/x", b'{"x": 1}', "counter sample 151 has no integer t_ns"),
        ("@redline/markers", b"1", "phase marker 3 is not an object"),
        ("@redline/driver/x", b'{"t_ns": "soon"}', "driver report 1 has a t_ns that is not"),
        ("@redline/counters/x", b"[" * 100_000 + b"]" * 100_000, "counter sample 151 is not JSON"),
        ("@redline/markers", b"[" * 100_000 + b"]" * 100_000, "RecursionError"),
        # a reviewer's: a whole number no float holds (OverflowError at ingestion), and a
        # Publish report's count that is text (TypeError)
        (
            "@redline/counters/x",
            b'{"t_ns": 1, "process": "x", "values": {"cpu": 1' + b"0" * 400 + b"}}",
            "counter sample 151 has a number too large for a float",
        ),
        (
            "@redline/driver/x",
            b'{"action": "Publish", "published": "x"}',
            "driver report 1 has a published count that is not a number",
        ),
    ],
)
def test_a_recording_holding_a_message_redline_does_not_write_is_refused_naming_it(
    api: Api, tmp_path: Path, topic: str, data: bytes, words: str
):
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    recording = recording_for(job, tmp_path / "r1.mcap", extra=(topic, data))
    _assert_refused(api, job["id"], recording, words)


def test_recording_made_for_another_job_is_refused(api: Api, tmp_path: Path):
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    data = recording_for(job, tmp_path / "r1.mcap", revision_title="r0")
    _assert_refused(api, job["id"], data, "revision_title is 'r0'")


def test_checksum_mismatch_is_400_and_keeps_the_job_leased(api: Api, tmp_path: Path):
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    data = recording_for(job, tmp_path / "r1.mcap")
    answer = api.upload(job["id"], data, sha256="0" * 64)
    assert answer.status_code == 400 and "X-Redline-Sha256" in answer.json()["detail"]
    assert api.job(job["id"])["state"] == "leased"
    assert api.upload(job["id"], data).status_code == 201


def test_upload_over_the_size_limit_is_413(api: Api):
    api.component()
    api.revision("r1", "1")
    job = api.lease()
    answer = api.upload(job["id"], b"\0" * (api.settings.max_upload_bytes + 1))
    assert answer.status_code == 413
    assert _executions(api) == 0 and api.job(job["id"])["state"] == "leased"


def _measured_history(api: Api, tmp_path: Path) -> None:
    """r1, r2 alike; r3 triples cpu. Uploaded over the API, ingested and detected directly."""
    api.component()
    for number, cpu in ((1, 20.0), (2, 20.0), (3, 60.0)):
        api.revision(f"r{number}", str(number))
        job = api.lease()
        data = recording_for(job, tmp_path / f"r{number}.mcap", cpu=cpu, seed=number)
        execution_id = api.upload(job["id"], data).json()["execution_id"]
        for revision_id in ingest_execution(api.settings.database_url, execution_id):
            detect_revision(api.settings.database_url, revision_id)


def test_series_and_changes_report_the_tripled_counter(api: Api, tmp_path: Path):
    _measured_history(api, tmp_path)
    series = {s["counter"]: s for s in api.client.get("/api/v1/components/builder/series").json()}
    cpu = series["cpu"]
    assert [p["revision"] for p in cpu["points"]] == ["r1", "r2", "r3"]
    assert cpu["points"][2]["mean"] == pytest.approx(3 * cpu["points"][0]["mean"], rel=0.1)
    assert cpu["params"] == {"rate": 10} and cpu["points"][0]["n"] == 150
    changes = api.client.get("/api/v1/components/builder/changes?flagged=true").json()
    assert [(c["revision"], c["series"]["counter"], c["method"]) for c in changes] == [
        ("r3", "cpu", "ks")
    ]
    assert changes[0]["baseline"] == "r2" and changes[0]["effect"] > 1.5
    assert [r["state"] for r in api.client.get("/api/v1/components/builder/revisions").json()] == [
        "done"
    ] * 3


def test_trend_page_draws_the_flagged_revision_with_local_plotly(api: Api, tmp_path: Path):
    _measured_history(api, tmp_path)

    def marked(query: str) -> dict[str, list[str]]:
        page = api.client.get(f"/components/builder{query}")
        assert page.status_code == 200
        assert '<script src="/static/plotly.min.js">' in page.text
        assert "cdn" not in page.text.lower()
        charts = trend_data(page.text)["charts"]
        assert len(charts) == 2  # drawn by the page from its data
        return {
            chart["figure"]["layout"]["yaxis"]["title"]["text"]: [
                x
                for trace in chart["figure"]["data"]
                if trace.get("name", "").startswith("change")
                for x in trace["x"]
            ]
            for chart in charts
        }

    # KS, charted by default, does not alarm: its flag is drawn when asked for (`flags=1`)
    assert marked("?flags=1") == {"cpu": ["r3"], "rss": []}
    assert marked("") == {"cpu": [], "rss": []}
    script = api.client.get("/static/plotly.min.js")
    assert script.status_code == 200 and len(script.content) > 1_000_000
    assert 'href="/components/builder"' in api.client.get("/").text


def test_an_address_naming_an_id_past_any_stored_one_is_404_for_every_method(api: Api):
    """A trial's heartbeat for a job id past 64 bits was a 422 "integer out of range", where
    the same id's GET was a 404."""
    for path in (f"/api/v1/jobs/{2**64}/heartbeat", f"/api/v1/jobs/{2**40}/release"):
        answer = api.post(path, "agent", {"host": "perf1"})
        assert answer.status_code == 404, answer.text
        assert "an id out of range" in answer.json()["detail"]


def test_head_answers_as_get_without_the_body_on_every_address_that_answers_get(api: Api):
    """A trial's `curl -I` of pages that exist got 404, of /healthz 405: uptime and link
    checkers ask with HEAD. Through a real uvicorn, whose HTTP framing must stay whole."""
    api.client.post(
        "/api/v1/components", headers=api.tokens["admin"], json={"name": "headed", "repo": ""}
    )
    with live_server(api.settings) as url, httpx.Client(base_url=url) as client:
        for path in ("/", "/components/headed", "/regressions", "/healthz",
                     "/api/v1/components", "/static/plotly.min.js"):  # fmt: skip
            got, head = client.get(path), client.head(path)
            assert got.status_code == 200, (path, got.text[:200])
            assert (head.status_code, head.content) == (200, b""), path
            assert head.headers["content-type"] == got.headers["content-type"], path
            if "content-length" in got.headers:
                assert head.headers["content-length"] == got.headers["content-length"], path
        missing = client.head("/components/nosuch")
        assert (missing.status_code, missing.content) == (404, b"")
        assert client.get("/healthz").json()  # the connection after the HEADs still answers
