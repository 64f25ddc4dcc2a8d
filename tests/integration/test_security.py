"""Least privilege at the edges: where a performance host's code comes from, which repository a
push names (real Postgres and Redis through the app, real git). The rules themselves, the
checkout and what charts and logs show are in tests/unit/test_security.py; what the agent takes
from a lease, against a real HTTP server."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from redline.agent.client import ServerClient
from redline.server.db import session_factory
from redline.server.models import Revision
from sqlalchemy import update

from tests.support.api import Api, api_with
from tests.support.receivers import http_receiver
from tests.support.servers import Services
from tests.support.webhooks import SECRET, counts, send_github, send_gitlab

REPO = "https://github.com/org/builder.git"


@pytest.fixture
def api(services: Services, tmp_path: Path) -> Iterator[Api]:
    with api_with(services, tmp_path, webhook_secret=SECRET) as api:
        api.post(
            "/api/v1/components",
            "admin",
            {"name": "builder", "repo": REPO, "suite": "perf/redline.toml"},
        ).raise_for_status()
        api.post("/api/v1/agent/register", "agent", {"name": "perf1"}).raise_for_status()
        yield api


def _revision(api: Api, scope: str = "ci", **extra: str) -> object:
    return api.post(
        "/api/v1/revisions",
        scope,
        {"component": "builder", "title": "r1", "sort_key": "1", "commit": "a" * 40, **extra},
    )


def test_a_ci_token_cannot_make_a_revision_run_another_repository(api: Api):
    for scope in ("ci", "admin"):  # a revision never moves a component: that is a setting
        answer = _revision(api, scope, repo="https://evil.example/payload.git")
        assert answer.status_code == 403, answer.text
        assert "builder" in answer.json()["detail"] and "PATCH" in answer.json()["detail"]
    assert counts(api) == (0, 0)
    same = _revision(api, repo="git@github.com:Org/Builder")  # the component's own, respelt
    assert same.status_code == 201, same.text
    job = api.post("/api/v1/agent/lease", "agent", {"host": "perf1"}).json()
    assert job["repo"] == REPO


def test_a_leased_job_carries_the_components_repository_not_a_stored_override(api: Api):
    assert _revision(api).status_code == 201
    with session_factory(api.settings.database_url)() as session:  # as an older version stored
        session.execute(update(Revision).values(repo="https://evil.example/payload.git"))
        session.commit()
    job = api.post("/api/v1/agent/lease", "agent", {"host": "perf1"}).json()
    assert job["repo"] == REPO


@pytest.mark.parametrize(
    "repo",
    [
        "--upload-pack=touch /tmp/pwned",
        "-uevil",
        "ext::sh -c touch% /tmp/pwned",
        "fd::17",
        "http://git.example/x.git",
        "ftp://git.example/x.git",
        "relative/path.git",
        "/srv/git/builder.git",
        "file:///srv/git/builder.git",
        "https://git.example/x\n.git",
        "ssh://-oProxyCommand=touch% /tmp/pwned/repo",
        "ssh://git@-oProxyCommand=x/repo",
        "git@-oProxyCommand=x:repo",
    ],
)
def test_component_repositories_are_refused_outside_the_allowed_schemes(api: Api, repo: str):
    created = api.post("/api/v1/components", "admin", {"name": "other", "repo": repo})
    assert created.status_code == 422, created.text
    assert "repo" in created.text
    patched = api.client.patch(
        "/api/v1/components/builder", json={"repo": repo}, headers=api.tokens["admin"]
    )
    assert patched.status_code == 422, patched.text
    assert api.client.get("/api/v1/components/builder").json()["repo"] == REPO


@pytest.mark.parametrize(
    "repo",
    [
        "https://github.com/org/x.git",
        "ssh://git@github.com:22/org/x.git",
        "git://host/x.git",
        "git@github.com:org/x.git",
        "",
    ],
)
def test_component_repositories_in_the_allowed_schemes_are_kept(api: Api, repo: str):
    created = api.post("/api/v1/components", "admin", {"name": "other", "repo": repo})
    assert created.status_code == 201, created.text


@pytest.mark.parametrize(
    "repo",
    [
        "https://ci-bot:SECRETSECRET@github.com/org/private.git",
        "https://SECRETSECRET@github.com/org/private.git",  # a token as the user
        "git://u:SECRETSECRET@host/x.git",
        "ssh://git:SECRETSECRET@host/x.git",
        "https://ci:SECRET@SECRET@github.com/org/private.git",  # a raw '@' in the password
    ],
)
def test_a_repository_url_carrying_a_password_or_token_is_refused_never_echoed(api: Api, repo: str):
    """A security review's admin set such a URL: the API and the pages showed it to every
    reader, and a host would have put it on git's command line, visible in ps."""
    created = api.post("/api/v1/components", "admin", {"name": "other", "repo": repo})
    assert created.status_code == 422 and "password or token" in created.text, created.text
    patched = api.client.patch(
        "/api/v1/components/builder", json={"repo": repo}, headers=api.tokens["admin"]
    )
    assert patched.status_code == 422 and "credential helper" in patched.text
    assert "SECRET" not in created.text + patched.text
    assert api.client.get("/api/v1/components/builder").json()["repo"] == REPO


def test_local_repositories_only_when_the_server_allows_them(services: Services, tmp_path: Path):
    folder = tmp_path / "git" / "builder.git"
    folder.mkdir(parents=True)
    with api_with(services, tmp_path, allow_file_repos=True) as api:
        for repo in (str(folder), f"file://{folder}"):
            answer = api.post(
                "/api/v1/components", "admin", {"name": f"c{len(repo)}", "repo": repo}
            )
            assert answer.status_code == 201, answer.text
        # a path that is no folder here is said so at once (a trial's mistyped path was taken,
        # and its first job failed inside a long git command line)
        for repo in ("/srv/git/nope.git", "file:///srv/git/nope.git"):
            answer = api.post("/api/v1/components", "admin", {"name": "nope", "repo": repo})
            assert answer.status_code == 422 and "no such folder on this machine" in answer.text
        assert (
            api.post(
                "/api/v1/components", "admin", {"name": "rel", "repo": "relative/path.git"}
            ).status_code
            == 422
        )


# --- which components a push is for -----------------------------------------------------------


def test_a_push_is_matched_by_its_clone_urls_never_its_homepage(api: Api):
    """Any repository admin sets ``homepage``; only the URLs the forge derives name it."""
    body = json.dumps(
        {
            "ref": "refs/heads/main",
            "commits": [{"id": "c" * 40, "message": "x", "timestamp": "2026-11-20T10:00:00Z"}],
            "repository": {
                "clone_url": "https://github.com/mallory/tool.git",
                "html_url": "https://github.com/mallory/tool",
                "homepage": "https://github.com/org/builder",
            },
        }
    ).encode()
    answer = send_github(api, body)
    assert answer.status_code == 202, answer.text
    assert counts(api) == (0, 0)


def test_a_gitlab_push_is_matched_by_its_clone_urls_never_its_homepage(api: Api):
    """GitLab sends ``homepage`` in both ``project`` and ``repository``: it names nothing."""

    def push(own: str) -> bytes:
        urls = {
            "git_http_url": f"https://gitlab.com/{own}.git",
            "git_ssh_url": f"git@gitlab.com:{own}.git",
            "web_url": f"https://gitlab.com/{own}",
            "homepage": "https://github.com/org/builder",
        }
        return json.dumps(
            {
                "object_kind": "push",
                "ref": "refs/heads/main",
                "commits": [{"id": "c" * 40, "message": "x", "timestamp": "2026-11-20T10:00:00Z"}],
                "project": urls,
                "repository": {"url": urls["git_ssh_url"], "homepage": urls["homepage"]},
            }
        ).encode()

    answer = send_gitlab(api, push("mallory/tool"))
    assert answer.status_code == 202, answer.text
    assert counts(api) == (0, 0)
    api.client.patch(  # the same push from the repository it names is recorded
        "/api/v1/components/builder",
        json={"repo": "https://gitlab.com/mallory/tool.git"},
        headers=api.tokens["admin"],
    ).raise_for_status()
    assert send_gitlab(api, push("mallory/tool")).status_code == 200
    assert counts(api)[0] == 1


def test_a_ping_is_authenticated_by_a_components_own_secret(services: Services, tmp_path: Path):
    """With no server-wide secret, a component's own secret authenticates every event of its
    repository, a ping included (acknowledged, nothing recorded)."""
    with api_with(services, tmp_path) as api:
        api.post(
            "/api/v1/components",
            "admin",
            {"name": "builder", "repo": REPO, "webhook_secret": "own-secret-of-builder"},
        ).raise_for_status()
        body = json.dumps(
            {
                "zen": "Design for failure.",
                "hook_id": 1,
                "repository": {"clone_url": REPO, "html_url": "https://github.com/org/builder"},
            }
        ).encode()
        assert (
            send_github(api, body, secret="own-secret-of-builder", event="ping").status_code == 202
        )
        assert send_github(api, body, secret="wrong", event="ping").status_code == 401
        assert counts(api) == (0, 0)


# --- what a page shows as text -----------------------------------------------------------------


# --- secrets stay out of logs --------------------------------------------------------------


def test_a_database_error_does_not_quote_the_secret_it_was_writing(database_url: str):
    """An error while writing a component's webhook secret (or a subscription's, or a commit
    status's token) is logged with its traceback, whose text quoted the statement's parameters,
    the secret among them (a security review's find)."""
    from redline.server.db import get_engine
    from sqlalchemy import text
    from sqlalchemy.exc import DBAPIError

    secret = "whsec-not-for-the-log"
    with get_engine(database_url).connect() as conn, pytest.raises(DBAPIError) as raised:
        # fails beside the secret, as a constraint beside a secret's column does
        conn.execute(text("SELECT CAST(:secret AS text), 1 / 0"), {"secret": secret})
    assert "division by zero" in str(raised.value)
    assert secret not in str(raised.value) and "hidden due to hide_parameters" in str(raised.value)


@pytest.mark.parametrize("given", ['"x/../.."', "7.0", "true", "null"])
def test_the_agent_runs_no_job_whose_id_is_no_number(given: str):
    """A review: the id names the job's folders, which the agent empties; a server (or whoever
    sits in the middle of plain http) sending "x/../.." would have had it empty others."""
    with http_receiver() as server:
        server.bodies[LEASE] = b'{"id": %s, "commit": "abc"}' % given.encode()
        client = ServerClient(server.url, "token", "perf1")
        with pytest.raises(ValueError, match="id is no number"):
            client.lease()
        server.bodies[LEASE] = b'{"id": 7, "commit": "abc"}'
        assert client.lease() == {"id": 7, "commit": "abc"}


LEASE = "/api/v1/agent/lease"
