"""Tokens: issued hashed, scoped, listed, revoked (API and CLI); read access open or by token."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from urllib.parse import urlencode

import pytest
from redline.server.db import session_factory
from redline.server.models import ApiToken
from redline.server.services import signin
from redline.server.services.errors import BadRequest
from redline.server.services.signin import create_user
from redline.server.services.tokens import issue_token
from sqlalchemy import select

from tests.support import ROOT
from tests.support.api import Api, api_with
from tests.support.pages import sign_in
from tests.support.servers import Services


@pytest.fixture
def api(services: Services, tmp_path: Path) -> Iterator[Api]:
    with api_with(services, tmp_path) as api:
        yield api


def test_admin_issues_a_token_stored_only_as_its_hash(api: Api):
    answer = api.client.post(
        "/api/v1/tokens",
        headers=api.tokens["admin"],
        json={"name": "perf2", "scopes": ["agent"], "host": "perf2"},
    )
    assert answer.status_code == 201, answer.text
    secret = answer.json()["token"]
    with session_factory(api.settings.database_url)() as session:
        stored = session.scalar(select(ApiToken).where(ApiToken.name == "perf2"))
        assert stored is not None and secret not in stored.token_hash and stored.host == "perf2"
    listed = api.client.get("/api/v1/tokens", headers=api.tokens["admin"]).json()
    assert "token" not in listed[-1] and listed[-1]["name"] == "perf2"
    again = api.client.post(
        "/api/v1/tokens",
        headers=api.tokens["admin"],
        json={"name": "perf2", "scopes": ["agent"], "host": "perf2"},
    )
    assert again.status_code == 409
    bad = api.client.post(
        "/api/v1/tokens", headers=api.tokens["admin"], json={"name": "x", "scopes": ["root"]}
    )
    assert bad.status_code == 400 and "'root'" in bad.json()["detail"]
    assert api.client.get("/api/v1/tokens", headers=api.tokens["ci"]).status_code == 403


def test_use_is_recorded_and_revocation_is_immediate(api: Api):
    created = api.client.post(
        "/api/v1/tokens", headers=api.tokens["admin"], json={"name": "jenkins", "scopes": ["ci"]}
    ).json()
    assert created["last_used"] is None
    headers = {"Authorization": f"Bearer {created['token']}"}
    body = {"component": "ghost", "title": "r1", "sort_key": "1", "commit": "abc1234"}
    assert api.client.post("/api/v1/revisions", json=body, headers=headers).status_code == 404
    listed = {
        t["name"]: t for t in api.client.get("/api/v1/tokens", headers=api.tokens["admin"]).json()
    }
    assert listed["jenkins"]["last_used"] is not None
    revoked = api.client.delete("/api/v1/tokens/jenkins", headers=api.tokens["admin"])
    assert revoked.status_code == 200 and revoked.json()[0]["revoked"] is True
    assert api.client.post("/api/v1/revisions", json=body, headers=headers).status_code == 401
    assert (
        api.client.delete("/api/v1/tokens/jenkins", headers=api.tokens["admin"]).status_code == 404
    )


def test_a_token_named_by_digits_is_refused_and_one_named_so_before_can_be_revoked(api: Api):
    """A token named "2026" could not be revoked by its name: the digits were read as an id
    (404 "no live token named or numbered '2026'"); one named "12345678901" was "an id out of
    range". A new one is refused (its name would read as an id); one made before is found by
    its name when no token has that id."""
    refused = api.client.post(
        "/api/v1/tokens", headers=api.tokens["admin"], json={"name": "2026", "scopes": ["ci"]}
    )
    assert refused.status_code == 400 and "digits" in refused.json()["detail"], refused.text
    with session_factory(api.settings.database_url)() as session:
        for name in ("2026", "12345678901"):  # as an older Redline let them be named
            session.add(ApiToken(name=name, scopes=["ci"], token_hash=f"never-{name}"))
        session.commit()
    for name in ("2026", "12345678901"):
        revoked = api.client.delete(f"/api/v1/tokens/{name}", headers=api.tokens["admin"])
        assert revoked.status_code == 200, revoked.text
        assert [(t["name"], t["revoked"]) for t in revoked.json()] == [(name, True)]
    first = api.client.post(  # a token of its own to revoke by its id
        "/api/v1/tokens", headers=api.tokens["admin"], json={"name": "by-id", "scopes": ["ci"]}
    ).json()
    by_id = api.client.delete(f"/api/v1/tokens/{first['id']}", headers=api.tokens["admin"])
    assert by_id.status_code == 200 and by_id.json()[0]["id"] == first["id"]  # an id still is one
    # that id revoked, a live token named by it is what the number now names (a review saw
    # the revoked one answer 200, the live one left usable)
    with session_factory(api.settings.database_url)() as session:
        session.add(ApiToken(name=str(first["id"]), scopes=["ci"], token_hash="never-named"))
        session.commit()
    named = api.client.delete(f"/api/v1/tokens/{first['id']}", headers=api.tokens["admin"])
    assert named.status_code == 200, named.text
    assert [(t["name"], t["revoked"]) for t in named.json()] == [(str(first["id"]), True)]
    odd = api.client.delete("/api/v1/tokens/%C2%B2", headers=api.tokens["admin"])  # '²'
    assert odd.status_code == 404 and "no live token named or numbered" in odd.text, odd.text


def test_read_access_token_mode_needs_a_read_token(services: Services, tmp_path: Path):
    with api_with(services, tmp_path, read_access="token") as api:
        assert api.client.get("/api/v1/components").status_code == 401
        assert api.client.get("/").status_code == 401
        read = api.tokens["read"]
        assert api.client.get("/api/v1/components", headers=read).status_code == 200
        secret = read["Authorization"].removeprefix("Bearer ")
        assert api.client.get(f"/?token={secret}").status_code == 200
        # the charts' data, which the component page fetches on zoom and pan, reads the same way
        assert api.client.get("/components/nope/trends").status_code == 401
        assert api.client.get(f"/components/nope/trends?token={secret}").status_code == 404
        api.client.cookies.set("redline_token", secret)
        assert api.client.get("/api/v1/components").status_code == 200
        api.client.cookies.clear()
        assert api.client.get("/api/v1/components", headers=api.tokens["agent"]).status_code == 403
        # who triages reads what they triage; a pipeline's token reads only its verdicts
        assert api.client.get("/api/v1/components", headers=api.tokens["triage"]).status_code == 200
        assert api.client.get("/api/v1/components", headers=api.tokens["ci"]).status_code == 403


def test_a_session_reads_only_what_its_scopes_read(services: Services, tmp_path: Path):
    """A trial signed in with the ci token, which reads only verdicts, and its session read
    every page, the API and the recordings under REDLINE_READ_ACCESS=token. Such a sign-in is
    refused now; a session opened while reading was open reads what its scopes read."""
    with api_with(services, tmp_path, read_access="token") as api:
        with session_factory(api.settings.database_url)() as session:
            create_user(session, "pipeline", "correct horse battery", "ci")
        ci = api.tokens["ci"]["Authorization"].removeprefix("Bearer ")
        for signed in ({"token": ci}, {"name": "pipeline", "password": "correct horse battery"}):
            api.client.cookies.clear()
            refused = sign_in(api.client, signed, follow_redirects=False)
            assert refused.status_code == 403, refused.text[:300]
            assert "reads only revisions&#39; verdicts (scopes ci), not the pages" in refused.text
            with session_factory(api.settings.database_url)() as session:
                name, password = signed.get("name", ""), signed.get("password", "")
                opened = signin.sign_in(session, name, password, signed.get("token", ""))
            api.client.cookies.set(signin.SESSION_COOKIE, opened.secret)
            for path in ("/api/v1/components", "/", "/regressions", "/components/builder/trends"):
                refused = api.client.get(path, follow_redirects=False)
                assert refused.status_code == 403, (signed, path, refused.text[:200])
                assert "lacks the 'read' or 'triage' scope" in refused.text, refused.text[:300]
            verdict = api.client.get("/api/v1/components/builder/revisions/r1/verdict")
            assert verdict.status_code == 404, verdict.text  # read, and there is no r1
            page = api.client.get("/regressions", headers={"Accept": "text/html"})
            assert page.status_code == 403 and "<html" in page.text, page.text[:300]
            assert "lacks the &#39;read&#39; or &#39;triage&#39; scope" in page.text
            assert 'href="/signin?next=%2Fregressions"' in page.text
        api.client.cookies.clear()


def test_a_browser_asking_for_a_page_under_read_access_token_is_sent_to_sign_in(
    services: Services, tmp_path: Path
):
    """A trial's browser got `401 {"detail":"missing bearer token"}` on every page, and no way
    to the sign-in page that works; the API, and a script's fetch, still get 401 JSON."""
    browser = {"Accept": "text/html,application/xhtml+xml,*/*;q=0.8"}
    with api_with(services, tmp_path, read_access="token") as api:
        with session_factory(api.settings.database_url)() as session:
            create_user(session, "ada", "correct horse battery", "read")
        for path, back in (
            ("/", "/"),
            ("/components/builder?case=build", "/components/builder?case=build"),
            ("/regressions?state=new&token=rl_stale", "/regressions?state=new"),  # no secret
        ):
            answer = api.client.get(path, headers=browser, follow_redirects=False)
            assert answer.status_code == 303, (path, answer.text)
            assert answer.headers["location"] == "/signin?" + urlencode({"next": back})
        signin = api.client.get("/signin?next=/components/builder%3Fcase%3Dbuild", headers=browser)
        assert signin.status_code == 200 and 'value="/components/builder?case=build"' in signin.text
        assert api.client.get("/static/redline.css", headers=browser).status_code == 200
        fetch = {"Accept": "application/json"}  # the component page's script, for its charts
        for path, asked in (
            ("/api/v1/components", browser),
            ("/static/plotly.min.js", browser),
            ("/components/builder/trends", fetch),
        ):
            refused = api.client.get(path, headers=asked, follow_redirects=False)
            assert refused.status_code == 401, path
            assert refused.json() == {"detail": "missing bearer token"}
        assert api.client.get("/", follow_redirects=False).status_code == 401  # not a browser
        signed = sign_in(
            api.client,
            {"name": "ada", "password": "correct horse battery", "next": "/regressions"},
            follow_redirects=False,
        )
        assert signed.headers["location"] == "/regressions"
        assert api.client.get("/", headers=browser).status_code == 200


def test_revoking_a_token_or_disabling_a_user_ends_their_browser_sessions(api: Api):
    """A security review signed in with the admin token, revoked it, and the session it had
    opened still made a new admin token on the settings page (for up to 7 days)."""
    made = api.client.post(
        "/api/v1/tokens", headers=api.tokens["admin"], json={"name": "leaked", "scopes": ["admin"]}
    ).json()
    with session_factory(api.settings.database_url)() as session:
        create_user(session, "ada", "correct horse battery", "admin")
    for signed, revoke in (
        ({"token": made["token"]}, lambda: api.client.delete(
            "/api/v1/tokens/leaked", headers=api.tokens["admin"]).raise_for_status()),
        ({"name": "ada", "password": "correct horse battery"}, _disable("ada", api)),
    ):  # fmt: skip
        api.client.cookies.clear()
        assert sign_in(api.client, signed, follow_redirects=False).status_code == 303
        assert api.client.get("/settings", follow_redirects=False).status_code == 200
        revoke()
        ended = api.client.get("/settings", follow_redirects=False)
        assert ended.status_code in (303, 401, 403), ended.text[:300]
        assert 'name="csrf"' not in ended.text  # no form of the settings page to post


def _disable(name: str, api: Api) -> Callable[[], None]:
    """`redline user disable NAME`, as an admin runs it (a trial found no way to disable one)."""

    def disable() -> None:
        env = {**os.environ, "REDLINE_DATABASE_URL": api.settings.database_url}
        redline = [str(Path(sys.executable).parent / "redline"), "user"]
        done = subprocess.run([*redline, "disable", name], env=env, capture_output=True,
                              text=True, cwd=ROOT, timeout=60)  # fmt: skip
        assert done.returncode == 0 and f"disabled user {name}" in done.stdout, done.stderr
        listed = subprocess.run([*redline, "list"], env=env, capture_output=True, text=True,
                                cwd=ROOT, timeout=60).stdout  # fmt: skip
        assert f"{name}\tadmin\t" in listed and listed.rstrip().endswith("disabled"), listed

    return disable


def test_a_blank_token_name_is_refused(api: Api):
    """A trial's `redline token create ""` made a token with no name; the API took "   "."""
    for name in ("", "   "):
        refused = api.client.post(
            "/api/v1/tokens", headers=api.tokens["admin"], json={"name": name, "scopes": ["ci"]}
        )
        assert refused.status_code in (400, 422), refused.text
    blank = api.client.post(
        "/api/v1/tokens", headers=api.tokens["admin"], json={"name": "   ", "scopes": ["ci"]}
    )
    assert "must not be empty or blank" in blank.text


def test_a_token_name_with_a_control_character_is_422_naming_it_once_escaped(api: Api):
    """A trial's "weird\x07" was a 400 whose message escaped the name twice ('weird\\\\x07'),
    where docs/api.md promises a 422 naming the character, as for every name."""
    made = {"name": "weird\x07", "scopes": ["ci"]}
    refused = api.client.post("/api/v1/tokens", headers=api.tokens["admin"], json=made)
    assert refused.status_code == 422, refused.text
    (error,) = refused.json()["detail"]
    assert error["loc"] == ["body", "name"] and "'\\x07' at position 5" in error["msg"], error
    database = session_factory(api.settings.database_url)
    with database() as session, pytest.raises(BadRequest) as told:  # the CLI's and form's way
        issue_token(session, "weird\x07", "ci")
    assert told.value.detail.startswith("a token's name 'weird\\x07' must not"), told.value


def test_read_access_open_by_default(api: Api):
    assert api.client.get("/api/v1/components").status_code == 200
    assert api.client.get("/").status_code == 200


@pytest.mark.slow  # a real `redline` command each time
def test_cli_lists_and_revokes_tokens(api: Api):
    env = {**os.environ, "REDLINE_DATABASE_URL": api.settings.database_url}
    command = [str(Path(sys.executable).parent / "redline"), "token"]
    listed = subprocess.run(
        [*command, "list"], env=env, capture_output=True, text=True, cwd=ROOT, check=True
    ).stdout
    assert "\tci\tci\t" in listed and "never" in listed
    header = "id\tname\tscopes\thost\tlabels\tcomponents\tcreated\tlast used\tstate"
    assert listed.splitlines()[0] == header
    assert "\tagent\tagent\tperf1\tgpu,quiet\t" in listed  # the tests' agent token
    done = subprocess.run(
        [*command, "revoke", "ci"], env=env, capture_output=True, text=True, cwd=ROOT
    )
    assert done.returncode == 0 and "revoked" in done.stdout
    body = {"component": "ghost", "title": "r1", "sort_key": "1", "commit": "abc1234"}
    assert (
        api.client.post("/api/v1/revisions", json=body, headers=api.tokens["ci"]).status_code == 401
    )
    missing = subprocess.run(
        [*command, "revoke", "nobody"], env=env, capture_output=True, text=True, cwd=ROOT
    )
    assert missing.returncode == 1 and "nobody" in missing.stderr


@pytest.mark.slow  # a real `redline` command each time
def test_cli_creates_a_host_bound_token_one_live_per_name(api: Api):
    env = {**os.environ, "REDLINE_DATABASE_URL": api.settings.database_url}
    redline = str(Path(sys.executable).parent / "redline")

    def create(name: str, *options: str) -> subprocess.CompletedProcess[str]:
        command = [redline, "token", "create", name, *options]
        return subprocess.run(command, env=env, capture_output=True, text=True, cwd=ROOT)

    made = create("perf-1", "--scopes", "agent", "--host", "perf-1", "--labels", "x86, quiet")
    assert made.returncode == 0, made.stderr
    secret = made.stdout.strip()
    with session_factory(api.settings.database_url)() as session:
        stored = session.scalar(select(ApiToken).where(ApiToken.name == "perf-1"))
        assert stored is not None and stored.host == "perf-1" and stored.scopes == ["agent"]
        assert stored.labels == ["quiet", "x86"]
    own = {"Authorization": f"Bearer {secret}"}
    answer = api.client.post("/api/v1/agent/lease", json={"host": "perf-9"}, headers=own)
    assert answer.status_code == 403 and "perf-1" in answer.json()["detail"]
    again = create("perf-1", "--scopes", "agent", "--host", "perf-1")
    assert again.returncode == 1 and "'perf-1'" in again.stderr and not again.stdout
    # what was asked is wrong (2, as typer answers a bad option), not the state it met (1)
    anywhere = create("anywhere", "--scopes", "agent")
    assert anywhere.returncode == 2 and "--host" in anywhere.stderr and not anywhere.stdout
    bad = create("other", "--scopes", "root")
    assert bad.returncode == 2 and "'root'" in bad.stderr
    spaced = create("other", "--scopes", "agent", "--host", "h", "--labels", "two words")
    assert spaced.returncode == 2 and "labels: 'two words': " in spaced.stderr
    # bound to components, comma-separated as labels are; one that does not exist is refused
    api.component("builder")
    bound = create("gitlab-b", "--scopes", "ci", "--components", "builder")
    assert bound.returncode == 0, bound.stderr
    rows = subprocess.run(
        [redline, "token", "list"], env=env, capture_output=True, text=True, cwd=ROOT
    ).stdout.splitlines()
    assert rows[0].split("\t")[5] == "components", rows[0]
    assert {row.split("\t")[1]: row.split("\t")[5] for row in rows[1:]}["gitlab-b"] == "builder"
    unknown = create("gitlab-c", "--scopes", "ci", "--components", "buidler")
    assert unknown.returncode == 2 and "unknown component 'buidler'" in unknown.stderr


def test_a_database_command_without_a_database_says_so_without_a_traceback(tmp_path: Path) -> None:
    from redline.agent.network import free_port

    unreachable = f"postgresql+psycopg://postgres@127.0.0.1:{free_port()}/none"
    redline = str(Path(sys.executable).with_name("redline"))
    done = subprocess.run(
        [redline, "token", "list"],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "REDLINE_DATABASE_URL": unreachable},
    )
    assert done.returncode == 1
    assert "cannot reach the database" in done.stderr and "REDLINE_DATABASE_URL" in done.stderr
    assert "Traceback" not in done.stderr
