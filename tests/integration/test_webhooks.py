"""Push webhooks (GitHub, GitLab) through the real app on real Postgres."""

from __future__ import annotations

import json
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

import pytest
from redline.server.db import session_factory
from redline.server.models import Job
from redline.server.services import webhooks
from sqlalchemy import select

from tests.support.api import Api, api_with
from tests.support.servers import Services
from tests.support.webhooks import (
    COMMITS,
    SECRET,
    counts,
    github_push,
    send_github,
    send_gitlab,
)


@pytest.fixture
def api(services: Services, tmp_path: Path) -> Iterator[Api]:
    with api_with(services, tmp_path, webhook_secret=SECRET) as api:
        api.post(
            "/api/v1/components",
            "admin",
            {
                "name": "builder",
                "repo": "https://github.com/Org/Builder.git",
                "branch": "main",
                "suite": "perf/redline.toml",
                "executions": 2,
                "host_labels": ["quiet"],
            },
        ).raise_for_status()
        yield api


def test_a_pushed_commit_sorts_after_the_history_ci_reported_before_it(api: Api):
    """CI reports `git log -1 --format=%ct` (docs/ci.md); a push's sort key must order with it:
    a trial's pushed commit sorted before all of CI's (20261124 < 1795551380)."""
    earlier = int(datetime(2026, 11, 20, 8, tzinfo=UTC).timestamp())
    later = datetime(2026, 11, 20, 10, tzinfo=UTC).timestamp()
    for title, key, commit in (("ci-early", earlier, "c"), ("ci-late", int(later), "d")):
        body = {"component": "builder", "title": title, "sort_key": str(key), "commit": commit * 40}
        api.post("/api/v1/revisions", "ci", body).raise_for_status()
    assert send_github(api, github_push()).status_code == 200  # commits at 09:00
    listed = [r["title"] for r in api.client.get("/api/v1/components/builder/revisions").json()]
    assert listed == ["ci-early", "a" * 12, "b" * 12, "ci-late"], listed


def test_github_push_creates_a_revision_per_commit_with_jobs_per_execution(api: Api):
    answer = send_github(api, github_push())
    assert answer.status_code == 200, answer.text
    created = answer.json()["created"]
    assert [r["title"] for r in created] == ["a" * 12, "b" * 12]
    assert all(len(r["job_ids"]) == 2 for r in created)
    # same commit time: the order in the push decides
    pushed = int(datetime(2026, 11, 20, 9, tzinfo=UTC).timestamp())
    assert created[0]["sort_key"] == f"{pushed}.0000" < created[1]["sort_key"]
    listed = api.client.get("/api/v1/components/builder/revisions").json()
    assert [(r["commit"], r["branch"]) for r in listed] == [("a" * 40, "main"), ("b" * 40, "main")]
    with session_factory(api.settings.database_url)() as session:
        assert {tuple(job.labels) for job in session.scalars(select(Job))} == {("quiet",)}


def test_a_push_makes_no_revision_of_a_component_no_host_could_run(api: Api):
    """A review: CI's report to a component without a suite was refused (409), a push still
    made its revisions, and each job failed on its host (suite file not found)."""
    api.post(
        "/api/v1/components", "admin", {"name": "twin", "repo": "https://github.com/org/builder"}
    ).raise_for_status()  # the same repository, no suite
    answer = send_github(api, github_push())
    assert answer.status_code == 200, answer.text
    assert {r["component"] for r in answer.json()["created"]} == {"builder"}
    said = answer.json()["detail"]
    assert "for builder; none for component 'twin' has no suite set" in said, said
    assert api.client.get("/api/v1/components/twin/revisions").json() == []


def test_repeated_delivery_creates_nothing_twice(api: Api):
    assert send_github(api, github_push()).status_code == 200
    again = send_github(api, github_push())
    assert again.status_code == 200 and again.json()["created"] == []
    assert again.json()["existing"] == 2
    assert counts(api) == (2, 4)


def test_a_commit_ci_reported_under_its_full_sha_is_not_made_again_by_a_push(api: Api):
    """CI (README's example) titles a revision by the full SHA, a push by 12 digits."""
    body = {"component": "builder", "title": "a" * 40, "sort_key": "1", "commit": "a" * 40}
    assert api.post("/api/v1/revisions", "ci", body).status_code == 201
    answer = send_github(api, github_push())
    assert answer.status_code == 200, answer.text
    assert [r["title"] for r in answer.json()["created"]] == ["b" * 12]
    assert answer.json()["existing"] == 1 and counts(api) == (2, 4)


def test_a_commit_whose_title_another_commit_holds_is_refused_not_called_known(api: Api):
    """A trial pushed 3,000 ids sharing their first 12 hex digits: "1 revision(s) created, 2999
    already known", as if delivered before. Each such commit is refused, naming the holder."""
    twins = [
        {"id": "c" * 12 + f"{n:028x}", "message": f"twin {n}", "timestamp": "2026-11-20T10:00:00Z"}
        for n in range(3)
    ]
    answer = send_github(api, github_push(commits=twins))
    assert answer.status_code == 200, answer.text
    found = answer.json()
    assert [r["title"] for r in found["created"]] == ["c" * 12] and found["existing"] == 0
    assert [r["commit"] for r in found["refused"]] == [twins[1]["id"], twins[2]["id"]]
    assert (
        f"already has a revision {'c' * 12!r}, of commit {twins[0]['id']!r}"
        in (found["refused"][0]["reason"])
    )
    assert "2 commit(s) refused" in found["detail"]


def test_forged_signature_is_401_and_creates_nothing(api: Api):
    answer = send_github(api, github_push(), secret="guessed")
    assert answer.status_code == 401 and "signature" in answer.json()["detail"]
    unsigned = api.client.post("/api/v1/webhooks/github", content=github_push())
    assert unsigned.status_code == 401
    assert counts(api) == (0, 0)


@pytest.mark.parametrize(
    ("path", "header"),
    [
        ("/api/v1/webhooks/github", "X-Hub-Signature-256"),
        ("/api/v1/webhooks/gitlab", "X-Gitlab-Token"),
    ],
)
def test_a_delivery_without_its_signature_header_is_401_naming_the_header(api: Api, path, header):
    """A trial's unsigned GitHub delivery was told "webhook signature does not match"."""
    for given in ({}, {header: ""}):
        answer = api.client.post(path, content=github_push(), headers=given)
        assert answer.status_code == 401, answer.text
        assert answer.json()["detail"].startswith(f"the {header} header is missing"), answer.text
    assert counts(api) == (0, 0)


def test_unknown_repository_or_other_branch_is_202_and_creates_nothing(api: Api):
    answer = send_github(api, github_push(repo="https://github.com/org/ghost"))
    assert answer.status_code == 202
    assert answer.json()["detail"].startswith("no component matches")
    other = send_github(api, github_push(ref="refs/heads/feature"))
    assert other.status_code == 202 and "feature" in other.json()["detail"]
    tag = send_github(api, github_push(ref="refs/tags/v1"))
    assert tag.status_code == 202
    assert counts(api) == (0, 0)


def test_ping_is_acknowledged_and_ignored(api: Api):
    answer = send_github(api, github_push(), event="ping")
    assert answer.status_code == 202 and counts(api) == (0, 0)


def test_component_secret_overrides_the_setting(api: Api):
    api.client.patch(
        "/api/v1/components/builder",
        json={"webhook_secret": "own-secret-of-builder"},
        headers=api.tokens["admin"],
    ).raise_for_status()
    assert send_github(api, github_push()).status_code == 401
    assert send_github(api, github_push(), secret="own-secret-of-builder").status_code == 200
    shown = api.client.get("/api/v1/components/builder").json()
    assert shown["has_webhook_secret"] is True and "webhook_secret" not in shown
    # a secret a forge signs with is not one guessed (a trial set "x"), nor a branch an option
    for field, value, said in (
        ("webhook_secret", "x", "at least 16 characters"),
        ("branch", "-x", "must not start with '-'"),
    ):
        weak = api.client.patch(
            "/api/v1/components/builder", json={field: value}, headers=api.tokens["admin"]
        )
        assert weak.status_code == 422 and said in weak.text, weak.text
    assert send_github(api, github_push(), secret="own-secret-of-builder").status_code == 200


def test_a_repository_no_url_parser_reads_is_refused_never_a_500(api: Api):
    """A review (2026-12-06): "https://[x" (an unclosed IPv6 bracket) made `repo_key` raise, so
    a forged delivery answered 500 before its signature was checked where a component has a
    secret of its own, as did a ci report naming it and an admin's setting."""
    api.client.patch(
        "/api/v1/components/builder",
        json={"webhook_secret": "own-secret-of-builder"},
        headers=api.tokens["admin"],
    ).raise_for_status()
    forged = github_push(repo="https://[forged")
    assert send_github(api, forged, secret="guessed").status_code == 401
    assert send_gitlab(api, forged, token="guessed").status_code == 401
    report = {"component": "builder", "title": "t1", "sort_key": "1", "commit": "a" * 40}
    answer = api.post("/api/v1/revisions", "ci", {**report, "repo": "https://[x"})
    assert answer.status_code == 403 and "own repository" in answer.text, answer.text
    for change in ({"repo": "https://[x/org/repo"}, {"repo": "ssh://h:port/org/x.git"}):
        refused = api.client.patch(
            "/api/v1/components/builder", json=change, headers=api.tokens["admin"]
        )
        assert refused.status_code == 422 and "not a URL git can read" in refused.text
    made = api.post("/api/v1/components", "admin", {"name": "odd", "repo": "https://[x/o/r"})
    assert made.status_code == 422 and "not a URL git can read" in made.text
    assert counts(api) == (0, 0)
    shown = api.client.get("/api/v1/components/builder").json()
    assert shown["repo"] == "https://github.com/Org/Builder.git"  # nothing stored was lost


def test_gitlab_push_with_its_token_creates_revisions(api: Api):
    body = json.dumps(
        {
            "object_kind": "push",
            "ref": "refs/heads/main",
            "commits": COMMITS[:1],
            "project": {"git_ssh_url": "git@github.com:org/builder.git"},
        }
    )
    headers = {"X-Gitlab-Event": "Push Hook", "Content-Type": "application/json"}
    wrong = api.client.post(
        "/api/v1/webhooks/gitlab", content=body, headers={**headers, "X-Gitlab-Token": "nope"}
    )
    assert wrong.status_code == 401 and counts(api) == (0, 0)
    # GitLab sends the secret itself: a trial's wrong token was told the "signature" mismatched
    assert wrong.json()["detail"] == "webhook token (X-Gitlab-Token) does not match", wrong.text
    answer = api.client.post(
        "/api/v1/webhooks/gitlab", content=body, headers={**headers, "X-Gitlab-Token": SECRET}
    )
    assert answer.status_code == 200 and len(answer.json()["created"]) == 1
    assert counts(api) == (1, 2)


def test_component_settings_are_created_patched_and_shown(api: Api):
    shown = api.client.get("/api/v1/components/builder").json()
    assert (shown["host_labels"], shown["executions"], shown["has_webhook_secret"]) == (
        ["quiet"],
        2,
        False,
    )
    patched = api.client.patch(
        "/api/v1/components/builder",
        headers=api.tokens["admin"],
        json={"branch": "develop", "executions": 3},
    )
    assert patched.status_code == 200
    assert (patched.json()["branch"], patched.json()["suite"]) == ("develop", "perf/redline.toml")
    denied = api.client.patch(
        "/api/v1/components/builder", headers=api.tokens["ci"], json={"branch": "x"}
    )
    assert denied.status_code == 403
    assert send_github(api, github_push()).status_code == 202  # main no longer matches


def test_without_a_secret_every_delivery_is_told_so(services: Services, tmp_path: Path):
    """A trial: with no secret configured, a well-formed push was told "no webhook secret is
    configured" and a malformed body "signature does not match"."""
    with api_with(services, tmp_path) as bare:  # no REDLINE_WEBHOOK_SECRET, no component's own
        for body in (github_push(), b'{"not": "a push"}', b"not json"):
            answer = send_github(bare, body)
            assert answer.status_code == 401, answer.text
            assert "webhook secret is configured" in answer.json()["detail"], body
        # once a component has a secret of its own, a body Redline cannot read names no
        # repository: only the server-wide secret could verify it, which is what it is told (a
        # probe's, signed with its component's own secret, read "no webhook secret is
        # configured")
        bare.post(
            "/api/v1/components",
            "admin",
            {"name": "builder", "repo": "https://github.com/org/builder", "suite": "perf/r.toml"}
            | {"webhook_secret": "own-secret-of-builder"},
        ).raise_for_status()
        answer = send_github(bare, b"not json", secret="own-secret-of-builder")
        assert answer.json()["detail"].startswith(
            "no server-wide webhook secret is configured, and only it can verify this body: it "
            "is no push Redline can read ("
        ), answer.text
        assert counts(bare) == (0, 0)


def test_where_no_component_has_its_own_secret_a_forged_delivery_is_never_parsed(
    api: Api, monkeypatch: pytest.MonkeyPatch
):
    """An audit: a forged delivery had its body parsed as JSON, and its repository looked up,
    before its signature was refused. With only the server-wide secret in force, the HMAC comes
    first."""
    parsed: list[bytes] = []
    real = webhooks.parse_push

    def spy(body: bytes) -> webhooks.Push:
        parsed.append(body)
        return real(body)

    monkeypatch.setattr(webhooks, "parse_push", spy)
    forged = send_github(api, b"[" * 1000 + b"]" * 1000, secret="guessed")
    assert forged.status_code == 401, forged.text
    assert forged.json()["detail"] == "webhook signature (X-Hub-Signature-256) does not match"
    assert send_github(api, github_push(), secret="guessed").status_code == 401
    assert parsed == [] and counts(api) == (0, 0)
    assert send_github(api, github_push()).status_code == 200  # signed: parsed and recorded
    assert parsed == [github_push()]
