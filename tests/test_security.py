"""Least privilege at the edges: where a performance host's code comes from, which repository a
push names, what a chart shows as text (real Postgres and Redis through the app, real git)."""

from __future__ import annotations

import json
import logging
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from redline.agent.checkout import CheckoutError, CloneCache, refused_repo
from redline.server.db import session_factory
from redline.server.models import Revision
from redline.server.schemas.results import SeriesOut
from sqlalchemy import update

from tests.conftest import Services
from tests.intake import api_with
from tests.test_api import Api
from tests.test_webhooks import SECRET, counts, send_github

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


def test_local_repositories_only_when_the_server_allows_them(services: Services, tmp_path: Path):
    with api_with(services, tmp_path, allow_file_repos=True) as api:
        for repo in ("/srv/git/builder.git", "file:///srv/git/builder.git"):
            answer = api.post(
                "/api/v1/components", "admin", {"name": f"c{len(repo)}", "repo": repo}
            )
            assert answer.status_code == 201, answer.text
        assert (
            api.post(
                "/api/v1/components", "admin", {"name": "rel", "repo": "relative/path.git"}
            ).status_code
            == 422
        )


# --- the agent's own checks: it runs git, so it must never let input become an option ---------


def _git_repo(root: Path) -> tuple[Path, str]:
    repo = root / "src"
    repo.mkdir()
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t.invalid"]
    subprocess.run([*git, "init", "-q", "-b", "main"], cwd=repo, check=True)
    (repo / "file").write_text("x")
    subprocess.run([*git, "add", "-A"], cwd=repo, check=True)
    subprocess.run([*git, "commit", "-qm", "one"], cwd=repo, check=True)
    head = subprocess.run(
        ["git", "rev-parse", "HEAD"], cwd=repo, check=True, capture_output=True, text=True
    ).stdout.strip()
    return repo, head


def test_checkout_never_reads_a_repository_or_commit_as_a_git_option(tmp_path: Path):
    marker = tmp_path / "pwned"
    cache = CloneCache(tmp_path / "cache", allow_file=True)
    with pytest.raises(CheckoutError, match="must not start with '-'"):
        cache.checkout(f"--upload-pack=touch {marker}", "HEAD", "job-1")
    repo, head = _git_repo(tmp_path)
    with pytest.raises(CheckoutError, match="commit"):
        cache.checkout(str(repo), f"--orphan={marker}", "job-2")
    assert not marker.exists()
    tree = cache.checkout(str(repo), head, "job-3")
    assert (tree / "file").read_text() == "x"


def test_checkout_refuses_local_repositories_unless_allowed(tmp_path: Path):
    repo, head = _git_repo(tmp_path)
    with pytest.raises(CheckoutError, match="file"):
        CloneCache(tmp_path / "cache").checkout(str(repo), head, "job-1")
    with pytest.raises(CheckoutError, match="file"):
        CloneCache(tmp_path / "cache").checkout(f"file://{repo}", head, "job-1")


def test_repository_rules_name_the_reason():
    assert refused_repo("https://github.com/org/x.git", allow_file=False) is None
    assert refused_repo("git@github.com:org/x.git", allow_file=False) is None
    assert "scheme 'ext'" in (refused_repo("ext::sh -c x", allow_file=False) or "")
    assert "http" in (refused_repo("http://h/x.git", allow_file=False) or "")
    assert refused_repo("/srv/x.git", allow_file=True) is None


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


def test_a_ping_is_authenticated_by_a_components_own_secret(services: Services, tmp_path: Path):
    """With no server-wide secret, a component's own secret authenticates every event of its
    repository, a ping included (acknowledged, nothing recorded)."""
    with api_with(services, tmp_path) as api:
        api.post(
            "/api/v1/components",
            "admin",
            {"name": "builder", "repo": REPO, "webhook_secret": "own"},
        ).raise_for_status()
        body = json.dumps(
            {
                "zen": "Design for failure.",
                "hook_id": 1,
                "repository": {"clone_url": REPO, "html_url": "https://github.com/org/builder"},
            }
        ).encode()
        assert send_github(api, body, secret="own", event="ping").status_code == 202
        assert send_github(api, body, secret="wrong", event="ping").status_code == 401
        assert counts(api) == (0, 0)


# --- what a page shows as text -----------------------------------------------------------------


def test_chart_labels_are_text_not_markup():
    from redline.server.ui.figures import trend_figure

    link = '<a href="https://evil.example/phish">click</a>'
    series = SeriesOut(
        id=1,
        label=f"{link} / main",
        case=link,
        phase="main",
        params={},
        process="p",
        counter=link,
        kind="counter",
        worse="increase",
        judged=True,
        points=[{"revision": link, "sort_key": "1", "n": 3, "mean": 1.0, "std": 0.1}],
    )
    figure = json.dumps(trend_figure(series, []))
    assert "<a" not in figure and "&lt;a href" in figure


# --- secrets stay out of logs --------------------------------------------------------------


@pytest.fixture
def root_logging() -> Iterator[None]:
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)


def test_logged_urls_have_their_credentials_redacted(
    capfd: pytest.CaptureFixture[str], root_logging: None
):
    from redline.server.core.logs import configure

    configure(json_lines=False)
    access = logging.getLogger("uvicorn.access")
    access.info(
        '%s - "%s %s HTTP/%s" %d',
        "127.0.0.1:5",
        "GET",
        "/components/x?token=rl_secret123&view=1",
        "1.1",
        200,
    )
    logging.getLogger("redline").info("fetched %s", "/x?a=1&access_token=rl_other")
    logged = capfd.readouterr().err
    assert "rl_secret123" not in logged and "rl_other" not in logged
    assert "token=***" in logged and "view=1" in logged
