"""Hostile and malformed input at every door: a clear 4xx naming what is wrong, never a 500, and
nothing already stored is lost (real Postgres and Redis through the app)."""

from __future__ import annotations

import json
import logging
import re
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from urllib.parse import quote

import pytest
from fastapi.testclient import TestClient
from redline.server.app import create_app
from redline.server.core.config import Settings
from redline.server.db import session_factory
from redline.server.models import Job, JobState, Revision
from redline.server.schemas.imports import ResultsImport
from redline.server.services.imports import from_results, store_import
from sqlalchemy import select, text
from sqlalchemy.orm import Session

from tests.support.api import Api, api_with, commit_of
from tests.support.concurrency import interleave
from tests.support.history import regression_between
from tests.support.servers import Services
from tests.support.webhooks import SECRET, counts, github_push, send_github, send_gitlab

REPO = "https://github.com/org/builder.git"
DEEP = ("[" * 1000 + "]" * 1000).encode()


@pytest.fixture
def api(services: Services, tmp_path: Path) -> Iterator[Api]:
    with api_with(
        services,
        tmp_path,
        webhook_secret=SECRET,
        max_webhook_bytes=50_000,
        max_import_bytes=200_000,
        max_json_bytes=100_000,
    ) as api:
        api.post(
            "/api/v1/components",
            "admin",
            {"name": "builder", "repo": REPO, "suite": "perf/redline.toml"},
        ).raise_for_status()
        yield api


def _post_raw(api: Api, path: str, body: bytes, scope: str | None = "ci", **headers: str) -> object:
    auth = api.tokens[scope] if scope else {}
    return api.client.post(
        path, content=body, headers={**auth, "Content-Type": "application/json", **headers}
    )


def _results(revision: str = "r1", host: str = "", value: float = 1.0) -> dict:
    return {
        "component": "builder",
        "revision": revision,
        "sort_key": revision,
        "host": host,
        "results": [{"case": "c", "counter": "t", "values": [value, value]}],
    }


def _revision(api: Api, scope: str = "ci", **fields: object) -> object:
    return api.post(
        "/api/v1/revisions",
        scope,
        {"component": "builder", "title": "r1", "sort_key": "1", "commit": "abc1234", **fields},
    )


# --- 5: dates --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "when",
    [
        "9999-12-31T23:59:59-01:00",
        "0001-01-01T00:00:00+01:00",
        "3026-01-01T00:00:00Z",
        "1900-01-01T00:00:00Z",
    ],
)
def test_an_unreadable_or_absurd_commit_date_is_422_naming_the_field(api: Api, when: str):
    answer = _revision(api, committed_at=when)
    assert answer.status_code == 422, answer.text
    assert "committed_at" in answer.text
    assert api.client.get("/api/v1/components/builder/revisions").status_code == 200
    assert api.client.get("/components/builder").status_code == 200


@pytest.mark.parametrize("commit", ["--upload-pack=touch x", "-x", ".hidden", "a b"])
def test_a_commit_git_would_misread_is_422_saying_what_a_commit_may_be(api: Api, commit: str):
    """A trial from outside got pydantic's regular expression back ("String should match
    pattern '^[A-Za-z0-9_][\\w./@+-]*$'"); now the rule, in words, without "Value error"."""
    answer = _revision(api, commit=commit)
    assert answer.status_code == 422, answer.text
    (error,) = answer.json()["detail"]
    assert error["loc"][-1] == "commit"
    assert error["msg"].startswith("must be a commit hash, tag or branch: letters, digits"), error
    assert _revision(api, commit="release/v1.2+build@3", scope="admin").status_code == 201


@pytest.mark.parametrize("commit", ["main", "v1.2", "HEAD", "abc123", "release/v1.2+build@3"])
def test_a_ci_token_names_the_commit_it_reports_by_its_hash(api: Api, commit: str):
    """A fifth trial's ci token reported its branch ("main", the commit of the revision that
    had just failed CI on a confirmed regression) under a new title, its sort key just before
    that revision: the hosts measured the same commit again, and the failed revision, judged
    against it, passed (exit 0). A branch or tag moves: a report not an admin's names its
    commit by its hash, and one commit under two titles is one revision."""
    answer = _revision(api, commit=commit)
    assert answer.status_code == 422, answer.text
    said = answer.json()["detail"]
    assert f"commit {commit!r} is not a commit hash" in said and "admin" in said, said
    assert not api.client.get("/api/v1/components/builder/revisions").json()  # nothing made
    guilty = "ab12" * 10
    assert _revision(api, commit=guilty, title="r4").status_code == 201
    again = _revision(api, commit=guilty[:12], title="sneaky", sort_key="0")
    assert again.status_code == 200 and again.json()["title"] == "r4", again.text


def test_a_plausible_commit_date_is_stored_and_read_back(api: Api):
    assert _revision(api, committed_at="2026-11-20T10:00:00+01:00").status_code == 201
    shown = api.client.get("/api/v1/components/builder/revisions/r1").json()
    assert shown["committed_at"].startswith("2026-11-20T09:00:00")


def test_a_bad_commit_date_in_a_push_is_reported_and_the_other_commits_are_created(api: Api):
    commits = [
        {"id": "a" * 40, "message": "ok", "timestamp": "2026-11-20T10:00:00+01:00"},
        {"id": "b" * 40, "message": "bad", "timestamp": "9999-12-31T23:59:59-01:00"},
        {"id": "c" * 40, "message": "ok", "timestamp": "2026-11-20T11:00:00+01:00"},
    ]
    answer = send_github(api, github_push(commits=commits))
    assert answer.status_code == 200, answer.text
    assert [r["title"] for r in answer.json()["created"]] == ["a" * 12, "c" * 12]
    refused = answer.json()["refused"]
    assert [r["commit"] for r in refused] == ["b" * 40] and "timestamp" in refused[0]["reason"]
    listed = api.client.get("/api/v1/components/builder/revisions")
    assert listed.status_code == 200 and len(listed.json()) == 2


def test_an_unreadable_date_stored_by_an_earlier_version_is_cleared_by_the_migration(
    services: Services, tmp_path: Path
):
    from alembic import command
    from redline.server.db import alembic_config, migrate

    from tests.support.servers import fresh_database

    database_url, _ = fresh_database(services.database_url)
    command.upgrade(alembic_config(database_url), "0004")
    with session_factory(database_url)() as session:
        session.execute(
            text(
                "INSERT INTO component (name, repo, branch, suite, executions, created, repo_key, "
                "host_labels, description) VALUES ('old', '', 'main', '', 1, now(), '', '[]', '')"
            )
        )
        session.execute(
            text(
                "INSERT INTO revision (component_id, title, sort_key, order_key, commit, repo, "
                "branch, message, committed_at, created) VALUES (1, 'r1', '1', '011', '', '', '', "
                "'', '9999-12-31T23:59:59-01:00', now())"
            )
        )
        session.commit()
    migrate(database_url)
    settings = Settings(
        database_url=database_url, redis_url=services.redis_url, storage_dir=tmp_path / "storage"
    )
    with TestClient(create_app(settings)) as client:
        listed = client.get("/api/v1/components/old/revisions")
        assert listed.status_code == 200, listed.text
        assert listed.json()[0]["committed_at"] is None


# --- 6: nesting --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "path,scope,refused",
    [
        ("/api/v1/import/lnt?component=builder", "ci", 400),
        ("/api/v1/import/results", "ci", 422),
        ("/api/v1/revisions", "ci", 422),
        ("/api/v1/components", "admin", 422),
    ],
)
def test_json_nested_too_deep_is_a_4xx_without_a_traceback(
    api: Api, path: str, scope: str, refused: int, caplog: pytest.LogCaptureFixture
):
    with caplog.at_level(logging.ERROR):
        answer = _post_raw(api, path, DEEP, scope)
    assert answer.status_code == refused, answer.text
    assert "nested deeper than 32" in answer.text
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]


@pytest.mark.parametrize("send", [send_github, send_gitlab], ids=["github", "gitlab"])
def test_a_signed_webhook_nested_too_deep_is_400_naming_the_nesting_without_a_traceback(
    api: Api, send: Callable[[Api, bytes], object], caplog: pytest.LogCaptureFixture
):
    """Signed with the server's secret, so the body is read (an unsigned delivery is 401 before
    it is: that proves nothing about the nesting)."""
    with caplog.at_level(logging.ERROR):
        answer = send(api, DEEP)
    assert answer.status_code == 400, answer.text
    assert "nested deeper than 32" in answer.json()["detail"]
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert counts(api) == (0, 0)


def test_nesting_python_can_parse_is_refused_too(api: Api):
    """A 200-deep parameter would be stored, and break every page that reads it back."""
    body = _results()
    body["results"][0]["params"] = {"p": json.loads("[" * 200 + "]" * 200)}
    answer = _post_raw(api, "/api/v1/import/results", json.dumps(body).encode())
    assert answer.status_code == 422 and "nested deeper than 32" in answer.text


def test_a_number_too_long_for_python_is_422_in_words_a_client_can_act_on(api: Api):
    """A trial's 5,000-digit sort key was answered with Python's "use
    sys.set_int_max_str_digits() to increase the limit"."""
    body = (
        b'{"component": "builder", "title": "r1", "commit": "abc1234", "sort_key": ' + b"9" * 5000
    )
    answer = _post_raw(api, "/api/v1/revisions", body + b"}")
    assert answer.status_code == 422, answer.text
    assert "a number of 5000 digits, more than 4300: give it as text" in answer.text
    assert "sys." not in answer.text
    assert counts(api) == (0, 0)


# --- 7: size -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "path,limit",
    [
        ("/api/v1/webhooks/github", 50_000),
        ("/api/v1/import/results", 200_000),
        ("/api/v1/import/lnt?component=builder", 200_000),
        ("/api/v1/revisions", 100_000),
    ],
)
def test_an_oversized_body_is_413_naming_the_limit(api: Api, path: str, limit: int):
    body = b'{"x": "' + b"a" * (limit + 10) + b'"}'
    answer = _post_raw(api, path, body)
    assert answer.status_code == 413, answer.text[:200]
    assert str(limit) in answer.json()["detail"]


def _one_response(sock: socket.socket) -> bytes:
    """One whole HTTP response read from ``sock``: its head, then the body bytes the head
    announces, however the server's writes were cut into segments."""
    data = b""
    while b"\r\n\r\n" not in data and (chunk := sock.recv(65536)):
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    length = re.search(rb"(?im)^content-length: *(\d+)", head)
    while length and len(body) < int(length.group(1)) and (chunk := sock.recv(65536)):
        body += chunk
    return head + b"\r\n\r\n" + body


def test_an_oversized_body_without_a_length_is_413_before_it_is_all_sent(api: Api):
    """A chunked body (no Content-Length) is counted as it arrives: the server answers 413
    while the sender still holds most of it back."""
    import uvicorn
    from redline.agent.network import free_port

    port = free_port()
    server = uvicorn.Server(
        uvicorn.Config(create_app(api.settings), host="127.0.0.1", port=port, log_config=None)
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        for _ in range(200):
            if server.started:
                break
            thread.join(0.05)
        with socket.create_connection(("127.0.0.1", port), timeout=20) as sock:
            sock.sendall(
                b"POST /api/v1/webhooks/github HTTP/1.1\r\nHost: t\r\n"
                # signed (a missing signature is refused before the body is read at all)
                b"X-Hub-Signature-256: sha256=00\r\n"
                b"Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
            )
            for _ in range(6):  # 60 kB of a body that would go on: the limit is 50 kB
                sock.sendall(b"2710\r\n" + b"a" * 10_000 + b"\r\n")
            answer = _one_response(sock)
        assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
        assert b"50000" in answer
    finally:
        server.should_exit = True
        thread.join(10)
    assert counts(api) == (0, 0)


@pytest.mark.parametrize("bad", ["x" * 50_000, 10**400])
def test_a_422_quotes_only_a_short_excerpt_of_bad_input(api: Api, bad: object):
    body = _results()
    body["results"][0]["values"] = [bad]
    answer = _post_raw(api, "/api/v1/import/results", json.dumps(body).encode())
    assert answer.status_code == 422
    assert len(answer.content) < 2_000 and "values" in answer.text
    assert all(len(str(error["input"])) <= 80 for error in answer.json()["detail"]), answer.text


def test_a_422_of_many_bad_values_names_the_first_and_counts_the_rest(api: Api):
    """A trial's 1 MB import of 200,000 bad values answered 30.9 MB, one error per value."""
    body = _results()
    body["results"][0]["values"] = ["x"] * 20_000
    answer = _post_raw(api, "/api/v1/import/results", json.dumps(body).encode())
    assert answer.status_code == 422
    assert len(answer.content) < 5_000, len(answer.content)
    *named, more = answer.json()["detail"]
    assert [e["loc"] for e in named] == [["body", "results", 0, "values", i] for i in range(20)]
    assert more["msg"] == "and 19980 more errors"


# --- 8: strange strings and numbers, names that cannot be addressed ------------------------------

LONE = b'"\\ud800"'


@pytest.mark.parametrize(
    "path,body",
    [
        ("/api/v1/revisions", b'{"component": "builder", "title": ' + LONE + b', "sort_key": "1"}'),
        ("/api/v1/components", b'{"name": "x", "description": ' + LONE + b"}"),
        ("/api/v1/import/results", json.dumps(_results()).encode().replace(b'"c"', LONE)),
        (
            "/api/v1/import/lnt?component=builder",
            json.dumps(
                {
                    "format_version": "2",
                    "machine": {"name": "m"},
                    "run": {"llvm_project_revision": "1"},
                    "tests": [{"name": "X", "t": 1.0}],
                }
            )
            .encode()
            .replace(b'"X"', LONE),
        ),
    ],
)
def test_a_lone_surrogate_is_a_4xx_naming_it(api: Api, path: str, body: bytes):
    answer = _post_raw(api, path, body, "admin")
    assert answer.status_code in (400, 422), answer.text
    assert "surrogate" in answer.text


def test_a_lone_surrogate_in_a_signed_push_is_400(api: Api):
    body = github_push().replace(b'"first"', LONE)
    answer = send_github(api, body)
    assert answer.status_code == 400 and "surrogate" in answer.text
    assert counts(api) == (0, 0)


def test_a_nul_character_is_a_4xx_naming_where_it_is(api: Api):
    body = b'{"name": "x", "description": "a\\u0000b"}'
    answer = _post_raw(api, "/api/v1/components", body, "admin")
    assert answer.status_code == 422, answer.text
    assert "NUL" in answer.text and "$.description" in answer.text, answer.text
    push = send_github(api, github_push().replace(b'"first"', b'"fi\\u0000rst"'))
    assert push.status_code == 400 and "NUL" in push.text and "message" in push.text, push.text
    assert counts(api) == (0, 0)
    # a backslash followed by "u0000" is text like any other
    fine = b'{"name": "y", "description": "C:\\\\u0000"}'
    assert _post_raw(api, "/api/v1/components", fine, "admin").status_code == 201
    # in an address: a trial's GET was told "a value in the request cannot be stored:
    # PostgreSQL text fields cannot contain NUL (0x00) bytes", where nothing was stored
    for path in ("/api/v1/components/builder/revisions/%00", "/api/v1/components/a%00b"):
        missing = api.client.get(path)
        assert missing.status_code == 404, missing.text
        assert "holds a NUL character (%00)" in missing.text and "PostgreSQL" not in missing.text
    gone = api.client.delete("/api/v1/tokens/a%00", headers=api.tokens["admin"])  # any method
    assert gone.status_code == 404 and "holds a NUL character" in gone.text, gone.text
    page = api.client.get("/regressions?component=%00")
    assert page.status_code == 422 and "component holds a NUL character" in page.text, page.text


def test_a_surrogate_pair_is_text_like_any_other(api: Api):
    answer = _post_raw(
        api,
        "/api/v1/revisions",
        b'{"component": "builder", "title": "r\\ud83d\\ude00", "sort_key": "1", '
        b'"commit": "c1c1c1c"}',
    )
    assert answer.status_code == 201, answer.text
    assert api.client.get(f"/api/v1/components/builder/revisions/{quote('r😀')}").status_code == 200


def test_a_body_that_is_not_an_object_is_named_for_what_it_is(api: Api):
    lnt = _post_raw(api, "/api/v1/import/lnt?component=builder", b"[1, 2]")
    assert lnt.status_code == 400 and "must be a JSON object" in lnt.json()["detail"]
    push = send_github(api, b"[1, 2]")
    assert push.status_code == 400, push.text
    assert push.json()["detail"].startswith("not a push event") and "http" not in push.text


def test_an_lnt_integer_too_large_for_a_float_is_400_naming_the_metric(api: Api):
    body = (
        '{"format_version": "2", "machine": {"name": "m"}, "run": '
        '{"llvm_project_revision": "1"}, "tests": [{"name": "t", "size": ' + "9" * 400 + "}]}"
    )
    answer = _post_raw(api, "/api/v1/import/lnt?component=builder", body.encode())
    assert answer.status_code == 400, answer.text
    assert "size" in answer.json()["detail"]


@pytest.mark.parametrize("name", [".", "..", ".hidden", "-x"])
def test_component_names_that_cannot_be_a_path_segment_are_refused(api: Api, name: str):
    answer = api.post("/api/v1/components", "admin", {"name": name})
    assert answer.status_code == 422 and "name" in answer.text


@pytest.mark.parametrize("title", ["a/b", ".", "..", "tab\there"])
def test_revision_titles_that_cannot_be_a_path_segment_are_refused(api: Api, title: str):
    answer = _revision(api, title=title)
    assert answer.status_code == 422 and "title" in answer.text
    imported = _post_raw(api, "/api/v1/import/results", json.dumps(_results(title)).encode())
    assert imported.status_code == 422 and "revision" in imported.text
    lnt = _post_raw(
        api,
        "/api/v1/import/lnt?component=builder",
        json.dumps(
            {
                "format_version": "2",
                "machine": {"name": "m"},
                "run": {"llvm_project_revision": title},
                "tests": [{"name": "t", "time": 1.0}],
            }
        ).encode(),
    )
    assert lnt.status_code == 400 and "llvm_project_revision" in lnt.text


def test_a_title_with_url_characters_is_reachable_url_encoded(api: Api):
    title = "v1.2 rc?#%&+"
    assert _revision(api, title=title).status_code == 201
    path = f"/api/v1/components/builder/revisions/{quote(title, safe='')}"
    assert api.client.get(path).json()["title"] == title
    assert api.post(f"{path}/cancel", "ci", {}).status_code == 200


# --- 9: concurrent get-or-create -----------------------------------------------------------------


def test_two_imports_naming_a_new_host_and_revision_at_once_both_store(api: Api):
    def importer(value: float) -> Callable[[Session], object]:
        data = ResultsImport.model_validate(_results("r9", host="new-host", value=value))
        body = data.model_dump_json().encode()
        run = from_results(data)  # an admin's: its hosts measure 'builder'
        return lambda s: store_import(s, api.settings.storage_dir, run, body, admin=True)

    results = interleave(api.settings.database_url, importer(1.0), importer(2.0))
    assert [type(r).__name__ for r in results] == ["ImportResult", "ImportResult"], results
    detail = api.client.get("/api/v1/components/builder/revisions/r9").json()
    assert len(detail["jobs"]) == 2 and {j["host"] for j in detail["jobs"]} == {"new-host"}


def test_two_hosts_registering_one_name_at_once_both_succeed(api: Api):
    from redline.server.schemas.jobs import RegisterRequest
    from redline.server.services.jobs import register_host

    def register(label: str) -> Callable[[Session], object]:
        data = RegisterRequest(name="perf-new", labels=[label])
        return lambda s: register_host(s, data)

    results = interleave(api.settings.database_url, register("a"), register("b"))
    assert [type(r).__name__ for r in results] == ["Host", "Host"], results


def test_two_detection_settings_at_once_both_succeed(api: Api):
    from redline.server.schemas.regressions import DetectionConfigIn
    from redline.server.services.detection_config import set_config

    def configure(floor: float) -> Callable[[Session], object]:
        data = DetectionConfigIn(thresholds={"ks": {"min_effect": floor}})
        return lambda s: set_config(s, "builder", data)

    results = interleave(api.settings.database_url, configure(0.2), configure(0.3))
    assert not [r for r in results if isinstance(r, Exception)], results


def test_two_tokens_of_one_name_issued_at_once_leave_one_live(api: Api):
    from redline.server.services.errors import Conflict
    from redline.server.services.tokens import issue_token

    results = interleave(
        api.settings.database_url,
        lambda s: issue_token(s, "twin", "ci"),
        lambda s: issue_token(s, "twin", "ci"),
    )
    assert isinstance(results[0], tuple) and isinstance(results[1], Conflict), results


def test_concurrent_imports_over_http_lose_nothing(api: Api):
    answers: list[int] = []

    def send(index: int) -> None:
        body = json.dumps(_results(f"c{index // 2}", host=f"h{index // 4}", value=index))
        sent = _post_raw(api, "/api/v1/import/results", body.encode(), scope="admin")
        answers.append(sent.status_code)

    threads = [threading.Thread(target=send, args=(i,)) for i in range(16)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    assert sorted(answers) == [201] * 16


@pytest.mark.parametrize("suite", ["../../../etc/passwd", "/etc/passwd", "perf/../../x.toml"])
def test_a_suite_outside_the_repository_is_refused_when_it_is_set(api: Api, suite: str):
    """Not only when a job fails on a host, long after (a trial from outside, 2026-11-24)."""
    answer = api.post("/api/v1/components", "admin", {"name": "trav", "suite": suite})
    assert answer.status_code == 422 and "suite" in answer.text and "repository" in answer.text
    changed = api.client.patch(
        "/api/v1/components/builder", json={"suite": suite}, headers=api.tokens["admin"]
    )
    assert changed.status_code == 422 and "suite" in changed.text
    assert api.client.get("/api/v1/components/builder").json()["suite"] == "perf/redline.toml"


@pytest.mark.parametrize("field", ["repo", "branch", "suite"])
def test_a_setting_a_job_needs_is_never_emptied(api: Api, field: str):
    """A trial's PATCH of ``"repo": ""`` was saved, and its next revisions each failed on a
    host ("no repository is configured"); the settings page keeps a field left blank."""
    before = api.client.get("/api/v1/components/builder").json()
    emptied = api.client.patch(
        "/api/v1/components/builder", json={field: ""}, headers=api.tokens["admin"]
    )
    assert emptied.status_code == 422, emptied.text
    assert field in emptied.text and "cannot be emptied" in emptied.text
    assert api.client.get("/api/v1/components/builder").json() == before


def test_a_component_no_host_could_run_takes_imports_but_no_ci_report(api: Api):
    """A trial made a component with no repo and no suite, reported revisions to it (201), and
    saw each job fail on its host. Its report is 409 now, saying what to set (imports, which
    run nothing, are tested with such components in test_import.py). And a component's branch
    is never empty."""
    made = api.post("/api/v1/components", "admin", {"name": "imported", "branch": ""})
    assert made.status_code == 422 and "branch" in made.text
    assert api.post("/api/v1/components", "admin", {"name": "imported"}).status_code == 201
    body = {"component": "imported", "title": "r1", "sort_key": "1", "commit": "abc1234"}
    refused = api.post("/api/v1/revisions", "ci", body)
    assert refused.status_code == 409, refused.text
    said = refused.json()["detail"]
    assert "has no repo and no suite set" in said and "PATCH /api/v1/components/imported" in said
    assert api.client.get("/api/v1/components/imported/revisions").json() == []
    set_repo = {"repo": "https://git.example/imported.git"}
    api.client.patch("/api/v1/components/imported", json=set_repo, headers=api.tokens["admin"])
    assert "has no suite set" in api.post("/api/v1/revisions", "ci", body).json()["detail"]
    api.client.patch(
        "/api/v1/components/imported", json={"suite": "perf/s.toml"}, headers=api.tokens["admin"]
    )
    assert api.post("/api/v1/revisions", "ci", body).status_code == 201


def test_an_unknown_field_is_refused_naming_it_never_ignored(api: Api):
    """A trial from outside saw `suite` in a revision and `committed_at` in an import dropped
    without a word (2026-11-24)."""
    answer = _revision(api, suite="../../other/perf/redline.toml")
    assert answer.status_code == 422 and "suite" in answer.text
    imported = _post_raw(
        api,
        "/api/v1/import/results",
        json.dumps({**_results("r9"), "committed_at": "2026-01-01T00:00:00"}).encode(),
    )
    assert imported.status_code == 422 and "committed_at" in imported.text
    typo = api.post("/api/v1/components", "admin", {"name": "other", "exeuctions": 3})
    assert typo.status_code == 422 and "exeuctions" in typo.text


def test_a_body_sent_as_a_form_is_415_asking_for_json(api: Api):
    """`curl -d '{...}'` without its header sends a form: "Input should be a valid dictionary"
    named nothing the caller could fix (a trial)."""
    body = b'{"component": "builder", "title": "r1", "sort_key": "1", "commit": "c1c1c1c"}'
    answer = _post_raw(
        api, "/api/v1/revisions", body, **{"Content-Type": "application/x-www-form-urlencoded"}
    )
    assert answer.status_code == 415 and "Content-Type: application/json" in answer.text
    assert counts(api) == (0, 0)
    fine = _post_raw(api, "/api/v1/revisions", body, **{"Content-Type": "application/json"})
    assert fine.status_code == 201, fine.text


def test_a_422_quotes_a_body_as_the_json_it_came_as_with_secrets_masked(api: Api):
    """A trial's revision without its title answered ``"input": "{'commit': 'abc1234', ...}"``:
    the body quoted as a Python dict. It is quoted as JSON, cut short, secrets masked."""
    body = {"component": "nope", "sort_key": "1", "commit": "abc1234"}
    answer = api.client.post("/api/v1/revisions", json=body, headers=api.tokens["ci"])
    assert answer.status_code == 422, answer.text
    (error,) = [e for e in answer.json()["detail"] if e["loc"] == ["body", "title"]]
    assert error["input"].startswith('{"component": "nope"'), error
    assert "'" not in error["input"]
    # no name: the error is the whole body's, which holds the secret
    secret = {"webhook_secret": "s3cr3t-s3cr3t-s3cr3t", "repo": "https://h/x.git"}
    answer = api.client.post("/api/v1/components", json=secret, headers=api.tokens["admin"])
    assert answer.status_code == 422, answer.text
    (error,) = [e for e in answer.json()["detail"] if e["loc"] == ["body", "name"]]
    assert error["input"].startswith('{"webhook_secret": "***"'), error
    assert "s3cr3t-s3cr3t-s3cr3t" not in answer.text


def test_a_422_quotes_what_would_not_show_as_itself_as_escapes(api: Api):
    """The refusal of a branch holding U+202E quoted it raw in its ``input``: whatever read the
    answer saw the rest of the line reversed. Long inputs stay cut short after escaping."""
    body = {"component": "builder", "title": "r1", "sort_key": "1", "commit": "abc1234"}
    for branch, quoted in (("a\u202eb", "a\\u202eb"), ("\x85" * 60, "\\x85" * 19 + "...")):
        answer = api.post("/api/v1/revisions", "ci", body | {"branch": branch})
        assert answer.status_code == 422, answer.text
        (error,) = answer.json()["detail"]
        assert error["input"] == quoted, error


@pytest.mark.parametrize("field", ["case", "phase"])
def test_an_imported_test_name_the_sdk_would_refuse_is_422_naming_it(api: Api, field: str):
    """A trial's import of case "a/b*" was stored, and its JUnit said classname ".../a/b*"."""
    body = _results()
    body["results"][0][field] = "a/b*"
    answer = _post_raw(api, "/api/v1/import/results", json.dumps(body).encode())
    assert answer.status_code == 422, answer.text
    assert answer.json()["detail"][0]["loc"] == ["body", "results", 0, field], answer.text
    assert counts(api) == (0, 0)


def test_a_sort_key_given_as_a_whole_number_is_taken_as_its_text(api: Api):
    """The README says numeric keys compare as numbers; a trial's "sort_key": 12 was 422."""
    created = _revision(api, title="r12", sort_key=12)
    assert created.status_code == 201, created.text
    revision = api.client.get("/api/v1/components/builder/revisions/r12").json()
    assert revision["sort_key"] == "12"
    for bad in (True, 1.5, None):
        answer = _revision(api, title="rx", sort_key=bad)
        assert answer.status_code == 422 and "sort_key" in answer.text, (bad, answer.text)
    # JSON's 1e400 reads as infinity: a fifth trial was told "not inf", a value it never sent
    body = b'{"component": "builder", "title": "rx", "commit": "abc1234", "sort_key": 1e400}'
    answer = _post_raw(api, "/api/v1/revisions", body, "ci")
    assert (
        answer.status_code == 422
        and "too large to read as a JSON number: give it as text" in answer.text
    ), answer.text


def test_ci_and_a_webhook_reporting_one_commit_at_once_make_one_revision(api: Api):
    """A review: CI's report (titled by the full SHA) and the push's webhook (titled by 12
    digits) each looked for the commit, found none while the other was not yet committed, and
    each made a revision: one commit under two titles, measured twice."""
    from redline.server.models import Revision
    from redline.server.schemas.revisions import RevisionCreate
    from redline.server.services.revision_reports import report_revision
    from redline.server.services.webhooks import receive_push
    from sqlalchemy import select

    sha = "c" * 40
    body = github_push(
        repo=REPO.removesuffix(".git"),
        commits=[{"id": sha, "message": "m", "timestamp": "2026-11-20T10:00:00+01:00"}],
    )
    report = RevisionCreate(component="builder", title=sha, sort_key="1795165200", commit=sha)
    results = interleave(
        api.settings.database_url,
        lambda s: report_revision(s, report),
        lambda s: receive_push(s, body, lambda secret: True, SECRET),
    )
    assert not [r for r in results if isinstance(r, Exception)], results
    with session_factory(api.settings.database_url)() as session:
        titles = session.scalars(select(Revision.title)).all()
    assert titles == [sha], titles
    assert results[1][1].existing == 1 and results[1][1].created == [], results[1]


@pytest.mark.parametrize("path", ["/api/v1/import/results", "/api/v1/revisions"])
@pytest.mark.parametrize(
    ("given", "status", "said"),
    [
        (None, 401, "missing bearer token"),
        ("Bearer rl_made_up", 401, "invalid or revoked token"),  # an audit's: parsed, then 401
        ("read", 403, "lacks the 'ci' scope"),
    ],
)
def test_a_body_without_a_good_token_is_refused_before_it_is_read(
    api: Api, path: str, given: str | None, status: int, said: str
):
    """A trial sent 200 MB with no token to the import: the server read 35 MB of it before its
    413, where a webhook answers 401 unread; an audit's made-up token had 32 MiB of JSON read
    and parsed on the event loop before its 401. A route that takes a bearer token refuses a
    request without a live one of its scope before it reads the body."""
    pulled = []

    def body() -> Iterator[bytes]:
        for _ in range(20):
            pulled.append(1)
            yield b"a" * 50_000

    headers = {"Content-Type": "application/json"}
    if given is not None:
        headers.update(api.tokens.get(given, {"Authorization": given}))
    answer = api.client.post(path, content=body(), headers=headers)
    assert answer.status_code == status, answer.text[:200]
    assert said in answer.json()["detail"], answer.text[:200]
    assert len(pulled) <= 1, len(pulled)  # what the transport asks for before the app answers
    # with a token, the same route reads and judges the body as before
    assert _post_raw(api, path, b'{"x": 1}').status_code == 422


def test_a_sort_key_read_as_a_time_more_than_a_year_ahead_is_refused_naming_it(api: Api):
    """A trial's ci token gave a revision the time 4102444800 (2100) as its sort key: it sorted
    above every revision reported after it, and the overview showed it, failed (its commit
    could not be checked out), as the newest for good. Refused now, by report, by import and by
    an admin's correction; a build number, a key within the year and a date-like key are not."""
    far = "4102444800"
    body = {"component": "builder", "title": "future", "sort_key": far, "commit": "abc1234"}
    refused = api.post("/api/v1/revisions", "ci", body)
    assert refused.status_code == 422, refused.text
    assert "2100-01-01" in refused.text and "sort_key" in refused.text, refused.text
    assert api.client.get("/api/v1/components/builder/revisions").json() == []
    soon = str(int(time.time()) + 200 * 24 * 3600)  # a skewed clock: within the year
    taken = [("build", "12345"), ("soon", soon), ("dated", "20261207120000")]
    # dates and hours of ten digits, which read as Unix times years ahead too
    taken += [("hourly", "2026120712"), ("minutely", "2612071230")]
    for title, key in taken:
        fields = {"title": title, "sort_key": key, "commit": commit_of(title)}
        made = api.post("/api/v1/revisions", "ci", {**body, **fields})
        assert made.status_code == 201, made.text
    imported = api.post("/api/v1/import/results", "ci", {**_results("r9"), "sort_key": far})
    assert imported.status_code == 422 and "2100-01-01" in imported.text, imported.text
    path = "/api/v1/components/builder/revisions/soon"
    patched = api.client.patch(path, json={"sort_key": far}, headers=api.tokens["admin"])
    assert patched.status_code == 422 and "2100-01-01" in patched.text, patched.text


def test_an_admin_corrects_a_revision_sort_key_a_ci_token_gave_ahead_of_time(api: Api):
    """A ci token gave a revision a time months ahead (a skewed clock) as its sort key: it
    sorted above every revision reported after it, and with results stored it could not be
    deleted (409) nor changed (405). An admin corrects the key; a ci token cannot."""
    ahead = str(int(time.time()) + 300 * 24 * 3600)
    for title, key in (("future", ahead), ("later", "1764900000")):
        body = {"component": "builder", "title": title, "sort_key": key, "commit": commit_of(title)}
        assert api.post("/api/v1/revisions", "ci", body).status_code == 201

    def in_order() -> list[str]:  # as the server orders them (by its order key)
        return [r["title"] for r in api.client.get("/api/v1/components/builder/revisions").json()]

    assert in_order() == ["later", "future"]
    path, fix = "/api/v1/components/builder/revisions/future", {"sort_key": 1764800000}
    # refused, changing nothing, while what the old order decided is in use (a reviewer's find):
    # a regression ending at it, then a confirmation run against it not yet ended
    with session_factory(api.settings.database_url)() as session:
        future, later = (
            session.scalars(select(Revision).where(Revision.title == t)).one()
            for t in ("future", "later")
        )
        regression = regression_between(session, later, future)
        session.commit()
        refused = api.client.patch(path, json=fix, headers=api.tokens["admin"])
        assert refused.status_code == 409, refused.text
        assert f"#{regression.id}" in refused.json()["detail"]
        session.delete(regression)
        pair = Job(revision_id=later.id, execution_index=7, pair=1, confirms_revision_id=future.id)
        session.add(pair)
        session.commit()
        refused = api.client.patch(path, json=fix, headers=api.tokens["admin"])
        assert refused.status_code == 409 and "confirmation run" in refused.text, refused.text
        pair.state = JobState.cancelled
        session.commit()
    assert in_order() == ["later", "future"]
    refused = api.client.patch(path, json=fix, headers=api.tokens["ci"])
    assert refused.status_code == 403 and "admin" in refused.text, refused.text
    assert (
        api.client.patch(path, json={"title": "x"}, headers=api.tokens["admin"]).status_code == 422
    )
    unknown = api.client.patch(f"{path}-nope", json=fix, headers=api.tokens["admin"])
    assert unknown.status_code == 404, unknown.text
    answer = api.client.patch(path, json=fix, headers=api.tokens["admin"])
    assert answer.status_code == 200, answer.text
    assert in_order() == ["future", "later"]
    reanalysis = api.client.get("/api/v1/components/builder/reanalysis").json()
    assert reanalysis["state"] == "queued", reanalysis  # judged again in the new order


def test_a_corrected_sort_key_whose_reanalysis_cannot_be_queued_is_503_saying_what_to_do(
    services: Services, tmp_path: Path
):
    """The key is stored with the re-analysis's request, but the broker (here a port nothing
    listens on) cannot take the task: the answer says so, and how to send it again."""
    with api_with(services, tmp_path, redis_url="redis://127.0.0.1:9/0") as api:
        api.component()
        body = {"component": "builder", "title": "future", "sort_key": "1790000000"}
        assert api.post("/api/v1/revisions", "ci", {**body, "commit": "abc1234"}).status_code == 201
        answer = api.client.patch(
            "/api/v1/components/builder/revisions/future",
            json={"sort_key": "1764800000"},
            headers=api.tokens["admin"],
        )
        assert answer.status_code == 503, answer.text
        assert "POST /api/v1/components/builder/reanalysis" in answer.json()["detail"]
        (listed,) = api.client.get("/api/v1/components/builder/revisions").json()
        assert listed["sort_key"] == "1764800000"
        reanalysis = api.client.get("/api/v1/components/builder/reanalysis").json()
        assert reanalysis["state"] == "queued", reanalysis  # a POST sends it
