"""Imports: LNT's JSON report (format 2) and Redline's generic results, on real Postgres."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from redline.recording import SeriesKey, canonical_params
from redline.server.core.tasks import DETECT_TASK
from redline.server.db import lock_component, session_factory
from redline.server.models import Component, Delivery, Execution, Revision
from redline.server.models.base import utcnow
from redline.server.schemas.components import ComponentCreate
from redline.server.services.components import create_component
from redline.server.services.imports import ImportedRun, store_import
from redline.worker.statuses import commit_status
from sqlalchemy import event, select, update
from sqlalchemy.orm import Session

from tests.support.api import Api, api_with, commit_of
from tests.support.concurrency import waiting_on_a_lock
from tests.support.servers import Services


@pytest.fixture
def api(services: Services, tmp_path: Path) -> Iterator[Api]:
    with api_with(services, tmp_path) as api:
        api.post("/api/v1/components", "admin", {"name": "clang"}).raise_for_status()
        yield api


def lnt_report(order: str = "1234", scale: float = 1.0) -> dict:
    return {
        "format_version": "2",
        "machine": {"name": "bench-box", "os": "linux"},
        "run": {
            "start_time": "2026-11-20T10:00:00",
            "end_time": "2026-11-20T10:05:00",
            "llvm_project_revision": order,
        },
        "tests": [
            {
                "name": "nts.SingleSource/fib",
                "execution_time": [scale * v for v in (1.0, 1.1, 0.9, 1.05)],
                "compile_time": 2.5 * scale,
                "hash": "abc",
            },
            {"name": "nts.SingleSource/sort", "execution_time": 3.0 * scale},
        ],
    }


def send_lnt(api: Api, report: dict, scope: str = "ci", component: str = "clang") -> object:
    return api.client.post(
        f"/api/v1/import/lnt?component={component}",
        content=json.dumps(report).encode(),
        headers={**api.tokens[scope], "Content-Type": "application/json"},
    )


def test_lnt_report_becomes_a_revision_with_a_series_per_test_and_metric(api: Api):
    answer = send_lnt(api, lnt_report())
    assert answer.status_code == 201, answer.text
    assert (answer.json()["revision"], answer.json()["series"]) == ("1234", 3)
    series = api.client.get("/api/v1/components/clang/series").json()
    named = {(s["case"], s["counter"]): s for s in series}
    assert set(named) == {
        ("nts.SingleSource/fib", "execution_time"),
        ("nts.SingleSource/fib", "compile_time"),
        ("nts.SingleSource/sort", "execution_time"),
    }
    fib = named[("nts.SingleSource/fib", "execution_time")]
    assert fib["points"][0]["n"] == 4 and fib["points"][0]["mean"] == pytest.approx(1.0125)
    execution = api.client.get(f"/api/v1/executions/{answer.json()['execution_id']}").json()
    assert execution["host"] == "bench-box" and execution["metadata"] == {
        "imported": "lnt",  # a trial's said "json"
        "start_time": "2026-11-20T10:00:00+00:00",
        "end_time": "2026-11-20T10:05:00+00:00",
    }
    # the machine the report names is no performance host: the home page does not list it as
    # one, for ever offline (a trial)
    assert "bench-box" not in api.client.get("/").text


def test_same_report_twice_stores_it_once(api: Api):
    first = send_lnt(api, lnt_report())
    again = send_lnt(api, lnt_report())
    assert again.status_code == 200 and again.json()["created"] is False
    assert again.json()["execution_id"] == first.json()["execution_id"]
    assert len(api.client.get("/api/v1/components/clang/revisions").json()) == 1


def test_the_same_results_spelt_otherwise_are_one_execution(api: Api):
    """A trial imported one revision's samples again with its series in another order, its
    commit in capitals and its sort key "1.0": a new execution each time, counted again in
    every verdict (a confirmed regression was withdrawn after a few such imports)."""
    results = [
        {"case": "parse", "counter": "cpu", "values": [10.0, 10.5, 9.5]},
        {"case": "parse", "counter": "rss", "values": [1.0, 2.0]},
    ]
    body = {"component": "clang", "revision": "v1", "sort_key": "1", "commit": "0000001abc",
            "results": results}  # fmt: skip
    first = api.post("/api/v1/import/results", "ci", body)
    assert first.status_code == 201, first.text
    for spelt in (
        {**body, "results": results[::-1]},
        {**body, "commit": "0000001ABC"},
        {**body, "sort_key": "1.0"},
    ):
        again = api.post("/api/v1/import/results", "ci", spelt)
        assert again.status_code == 200 and again.json()["created"] is False, again.text
        assert again.json()["execution_id"] == first.json()["execution_id"]
    other = {**body, "results": [{**results[0], "values": [10.0, 10.5, 9.6]}, results[1]]}
    assert api.post("/api/v1/import/results", "ci", other).json()["created"] is True  # a new run


def test_malformed_lnt_reports_are_400_naming_the_fault(api: Api):
    version_one = {**lnt_report(), "format_version": "1"}
    assert (
        "'format_version' is '1': only \"2\" is read" in send_lnt(api, version_one).json()["detail"]
    )
    unversioned = lnt_report()
    del unversioned["format_version"]
    assert "'format_version' is missing" in send_lnt(api, unversioned).json()["detail"]
    no_order = lnt_report()
    del no_order["run"]["llvm_project_revision"]
    answer = send_lnt(api, no_order)
    assert answer.status_code == 400 and "llvm_project_revision" in answer.json()["detail"]
    nameless = {**lnt_report(), "tests": [{"execution_time": 1.0}]}
    assert "tests[0]" in send_lnt(api, nameless).json()["detail"]
    assert send_lnt(api, lnt_report(), component="ghost").status_code == 404
    assert send_lnt(api, lnt_report(), scope="agent").status_code == 403
    for field in ("git_sha", "commit"):  # a security review stored this as a commit
        forged = lnt_report()
        forged["run"][field] = "--upload-pack=touch /tmp/x?a=b#c"
        answer = send_lnt(api, forged)
        assert answer.status_code == 400 and f"run.{field}" in answer.json()["detail"], answer.text
        assert "git would read a leading '-'" in answer.json()["detail"]
    assert api.client.get("/api/v1/components/clang/revisions").json() == []


def test_names_too_long_to_keep_are_refused_not_cut_and_nothing_is_stored(api: Api):
    """A probe's two LNT tests named alike for their first 200 characters were pooled into one
    series (cut to 200, silently), its over-long machine name cut; 80 parameters of a generic
    result and a 3,000-letter repository were answered "the database is unavailable; try again
    later" (503): each is a 4xx naming what is too long, and nothing is stored."""
    report = lnt_report()
    report["tests"] = [
        {"name": "n" * 200 + "A", "execution_time": [1.0]},
        {"name": "n" * 200 + "B", "execution_time": [100.0]},
    ]
    answer = send_lnt(api, report)
    assert answer.status_code == 400, answer.text
    assert "tests[0].name 'nnnn" in answer.json()["detail"]
    assert "is 201 characters long (at most 200)" in answer.json()["detail"]
    report = lnt_report()
    report["machine"]["name"] = "m" * 5000
    answer = send_lnt(api, report)
    assert answer.status_code == 400 and "machine.name" in answer.json()["detail"], answer.text
    report = lnt_report(order="9" * 300)
    answer = send_lnt(api, report)
    assert answer.status_code == 400 and "llvm_project_revision" in answer.json()["detail"]

    def with_params(params: dict) -> object:
        one = {"case": "c", "params": params, "counter": "t", "values": [1.0]}
        body = {"component": "clang", "revision": "r1", "sort_key": "1", "results": [one]}
        return api.client.post("/api/v1/import/results", json=body, headers=api.tokens["ci"])

    answer = with_params({f"{n:02d}" + "k" * 18: "v" * 30 for n in range(80)})
    assert answer.status_code == 422, answer.text
    assert "is too long to store" in answer.json()["detail"] and "at most 2000" in answer.text
    assert api.client.get("/api/v1/components/clang/revisions").json() == []
    # a name in the path of a 422 is quoted in short too (a probe's answer was 100 kB)
    answer = with_params({"p" * 100_000: 1})
    assert answer.status_code == 422 and len(answer.content) < 2_000, len(answer.content)
    assert "pppp" in answer.text
    long_repo = {"name": "rr", "repo": "https://x.example/" + "a" * 3000}
    answer = api.post("/api/v1/components", "admin", long_repo)
    assert answer.status_code == 422 and "1000 characters" in answer.text, answer.text
    patched = api.client.patch(
        "/api/v1/components/clang", json={"repo": long_repo["repo"]}, headers=api.tokens["admin"]
    )
    assert patched.status_code == 422 and "1000 characters" in patched.text, patched.text


@pytest.mark.parametrize(
    ("field", "given", "said"),
    [
        ("start_time", "2026-02-30T10:00:00", "day is out of range for month"),
        ("start_time", "not a date", "not a valid ISO 8601 time"),
        ("start_time", "9999-01-01T00:00:00", "not between 1970-01-01 and a year from now"),
        ("start_time", 1795165200, "not a valid ISO 8601 time"),
        ("end_time", "2026-11-20T09:00:00", "before the run's start_time"),
    ],
)
def test_an_lnt_run_time_that_is_none_is_422_naming_the_field(api: Api, field, given, said):
    """A trial's reports with such start times were stored (201), as if they were times."""
    report = lnt_report()
    report["run"][field] = given
    answer = send_lnt(api, report)
    assert answer.status_code == 422, answer.text
    assert f"run.{field}" in answer.json()["detail"] and said in answer.json()["detail"]
    assert api.client.get("/api/v1/components/clang/revisions").json() == []


def test_generic_results_import_and_compare_two_revisions(api: Api):
    def results(revision: str, key: str, cpu: list[float]) -> dict:
        return {
            "component": "clang",
            "revision": revision,
            "sort_key": key,
            "host": "perf1",
            "results": [
                {"case": "parse", "params": {"legs": 8}, "counter": "cpu", "values": cpu},
                {"case": "parse", "params": {"legs": 4}, "counter": "cpu", "values": [1.0, 1.0]},
            ],
        }

    base = api.post(
        "/api/v1/import/results", "ci", results("r1", "1", [10.0 + i % 3 for i in range(30)])
    )
    assert base.status_code == 201, base.text
    cand = api.post(
        "/api/v1/import/results", "ci", results("r2", "2", [20.0 + i % 3 for i in range(30)])
    )
    assert cand.status_code == 201
    compared = api.client.get("/api/v1/components/clang/compare?base=r1&candidate=r2").json()
    legs8 = next(row for row in compared["series"] if row["series"]["params"] == {"legs": 8})
    assert legs8["change"] == pytest.approx(10 / 11) and legs8["ks_statistic"] == 1.0
    assert legs8["exact"] is True and legs8["baseline"]["n"] == 30
    missing = api.client.get("/api/v1/components/clang/compare?base=r1&candidate=r9")
    assert missing.status_code == 404 and "'r9'" in missing.json()["detail"]
    empty = api.post("/api/v1/import/results", "ci", {**results("r3", "3", [1.0]), "results": []})
    assert empty.status_code == 422


VALUES = ["body", "results", 0, "values", 1]
PARAMETER = ["body", "results", 0, "params", "n"]


@pytest.mark.parametrize(
    ("given", "where"),
    [
        *(
            (f'"values": [1.0, {value}]', VALUES)
            for value in (
                "NaN",
                "Infinity",
                "-Infinity",
                "1e400",
                "1e308",
                "-2e30",
                '"1.0"',
                "true",
            )
        ),
        # an audit's 400-digit whole-number parameter was stored, and the execution's page,
        # which charts a counter against a numeric parameter, answered 500
        *(
            (f'"params": {{"n": {value}}}, "values": [1.0]', PARAMETER)
            for value in ("1" + "0" * 400, "-2e30")
        ),
    ],
)
def test_non_finite_generic_values_are_422_naming_the_field(api: Api, given: str, where: list):
    """A trial's 1e308 was taken and broke the statistics (NaN means, a 300-digit change);
    its "1.0" was taken as a number, where the docs promise numbers."""
    body = (
        '{"component": "clang", "revision": "r1", "sort_key": "1", "results": '
        f'[{{"case": "parse", "counter": "cpu", {given}}}]}}'
    )
    answer = api.client.post(
        "/api/v1/import/results",
        content=body.encode(),
        headers={**api.tokens["ci"], "Content-Type": "application/json"},
    )
    assert answer.status_code == 422, answer.text
    assert [e["loc"] for e in answer.json()["detail"]] == [where], answer.text
    assert api.client.get("/api/v1/components/clang/revisions").json() == []


def test_one_series_given_twice_in_an_import_is_422_naming_both(api: Api):
    """A trial's two entries of one series were pooled without a word (a mean of 15)."""
    entry = {"case": "parse", "counter": "cpu", "params": {"n": 1}}
    body = {
        "component": "clang",
        "revision": "r1",
        "sort_key": "1",
        "results": [{**entry, "values": [10.0]}, {**entry, "counter": "rss", "values": [1.0]},
                    {**entry, "values": [20.0]}],
    }  # fmt: skip
    answer = api.post("/api/v1/import/results", "ci", body)
    assert answer.status_code == 422, answer.text
    assert "results[2] is the series of results[0] again" in answer.text
    assert api.client.get("/api/v1/components/clang/revisions").json() == []


def test_an_lnt_metric_too_large_to_measure_is_400_naming_it(api: Api):
    report = lnt_report()
    report["tests"][0]["execution_time"] = [1e308, 1e308]
    answer = send_lnt(api, report)
    assert answer.status_code == 400 and "beyond ±1e+30" in answer.json()["detail"], answer.text
    assert api.client.get("/api/v1/components/clang/revisions").json() == []


def test_a_series_without_a_finite_value_gets_no_summary(api: Api):
    params = canonical_params({})
    run = ImportedRun(
        "clang",
        "r1",
        "1",
        "",
        "",
        {
            SeriesKey("parse", "main", params, "benchmark", "cpu"): [float("nan"), float("inf")],
            SeriesKey("parse", "main", params, "benchmark", "rss"): [1.0, 2.0],
        },
    )
    with session_factory(api.settings.database_url)() as session:
        result = store_import(session, api.settings.storage_dir, run, b"one finite series")
    assert result.created and result.series == 1


def test_an_import_queues_detection_of_its_revision_once(api: Api):
    first = send_lnt(api, lnt_report())
    assert first.status_code == 201
    queued = [(DETECT_TASK, f"[{first.json()['revision_id']}]")]
    assert api.queued_tasks() == queued  # the task waits in the real broker
    assert send_lnt(api, lnt_report()).status_code == 200  # imported before: nothing new
    results = {
        "component": "clang",
        "revision": "r2",
        "sort_key": "2",
        "results": [{"case": "parse", "counter": "cpu", "values": [1.0, 2.0]}],
    }
    second = api.post("/api/v1/import/results", "ci", results)
    assert second.status_code == 201
    queued.append((DETECT_TASK, f"[{second.json()['revision_id']}]"))
    assert sorted(api.queued_tasks()) == sorted(queued)


def test_a_second_import_into_a_judged_revision_leaves_its_verdict_pending(api: Api):
    """A review: a run imported into a revision already judged left it marked analysed, so its
    verdict read "done" without that run until the queued detection came; and a detection
    under way as the import committed kept the mark for good. It is pending now, and its
    inputs counted up (`redline.server.services.analysed`)."""
    first = send_lnt(api, lnt_report())
    revision_id = first.json()["revision_id"]
    later = send_lnt(api, lnt_report("1235")).json()["revision_id"]  # it reads the first
    with session_factory(api.settings.database_url)() as session:
        session.execute(update(Revision).values(analyzed_at=utcnow()))
        session.commit()
        before = dict(session.execute(select(Revision.id, Revision.inputs)).all())
    report = lnt_report()
    report["machine"]["name"] = "bench-box-2"  # another run of the same revision
    second = send_lnt(api, report)
    assert second.status_code == 201 and second.json()["revision_id"] == revision_id
    with session_factory(api.settings.database_url)() as session:
        for judged_again in (revision_id, later):  # and the later one, whose baseline it is
            revision = session.get_one(Revision, judged_again)
            assert revision.analyzed_at is None and revision.inputs == before[judged_again] + 1


def test_an_import_never_joins_a_measured_revision_nor_another_commits(api: Api):
    """A ci token's import into a revision the agents measured made its confirmed regression's
    verdict pass (a trial's 16 imports of baseline-like values); one naming another commit
    than the revision's was stored beside it."""
    api.component()
    measured = api.revision("r1", "1")  # its job is queued for a performance host

    def results(revision: str, commit: str) -> dict:
        cpu = {"case": "parse", "params": {"legs": 8}, "counter": "cpu", "values": [1.0, 2.0]}
        body = {"component": "builder", "revision": revision, "sort_key": "1", "results": [cpu]}
        return {**body, "commit": commit}

    # an admin's imports (a ci token's are refused: `test_a_ci_token_cannot_import_...`)
    joined = api.post("/api/v1/import/results", "admin", results("r1", commit_of("r1")))
    assert joined.status_code == 409, joined.text
    assert f"measured by performance hosts (job {measured['job_ids'][0]})" in joined.text
    made = api.post("/api/v1/import/results", "admin", results("i1", "abc123"))
    assert made.status_code == 201, made.text
    other = api.post("/api/v1/import/results", "admin", results("i1", "deadbeef"))
    assert other.status_code == 409 and "of commit 'abc123'; this import says" in other.text
    same = api.post("/api/v1/import/results", "admin", {**results("i1", "abc123"), "host": "b"})
    assert same.status_code == 201  # a second execution of the imported revision
    with session_factory(api.settings.database_url)() as session:
        stored = session.scalars(select(Execution.revision_id)).all()
        assert len(stored) == 2 and measured["revision_id"] not in stored


def test_a_ci_token_cannot_import_what_performance_hosts_measure(api: Api):
    """A trial's ci token imported made-up results for a commit before reporting it: the report
    queued nothing, the gate passed a 4x CPU rise with a green commit status, and the made-up
    level hid the next commit's real regression. A component its hosts measure takes imports
    from an admin only; one for imported results alone (no repository or suite) from ci."""
    api.component()
    cpu = {"case": "parse", "counter": "cpu", "values": [1.0, 2.0]}
    forged = {"component": "builder", "revision": "fa468a4", "sort_key": "1", "commit": "fa468a4"}
    forged["results"] = [cpu]
    for path, body in (
        ("/api/v1/import/results", json.dumps(forged).encode()),
        ("/api/v1/import/lnt?component=builder", json.dumps(lnt_report("fa468a4")).encode()),
    ):
        refused = api.client.post(
            path, content=body, headers={**api.tokens["ci"], "Content-Type": "application/json"}
        )
        assert refused.status_code == 403, refused.text
        assert "measured by its performance hosts" in refused.json()["detail"]
        assert "admin token only" in refused.json()["detail"]
    assert api.client.get("/api/v1/components/builder/revisions").json() == []  # nothing kept
    reported = api.revision("fa468a4", "1")  # CI's report: its hosts measure it
    assert reported["job_ids"], reported

    with session_factory(api.settings.database_url)() as session:
        create_component(session, ComponentCreate(name="bench"))  # results imported only
    answer = api.post("/api/v1/import/results", "ci", {**forged, "component": "bench"})
    assert answer.status_code == 201, answer.text


def test_a_commit_imported_under_another_title_is_refused_naming_its_revision(api: Api):
    """A trial imported i12b with i11's commit and got a second revision of one commit, where a
    report of it under another title is the revision first reported (docs/api.md)."""

    def results(revision: str, commit: str) -> dict:
        cpu = {"case": "parse", "counter": "cpu", "values": [1.0, 2.0]}
        return {"component": "clang", "revision": revision, "sort_key": revision[1:],
                "commit": commit, "results": [cpu]}  # fmt: skip

    sha = "0000011abcdef0123456789"
    assert api.post("/api/v1/import/results", "ci", results("i11", sha)).status_code == 201
    for commit in (sha, sha[:12].upper()):
        again = api.post("/api/v1/import/results", "ci", results("i12", commit))
        assert again.status_code == 409, again.text
        assert f"commit {commit!r} is revision 'i11' of 'clang' already" in again.text
    moving = api.post("/api/v1/import/results", "ci", results("i12", "main"))
    assert moving.status_code == 201  # a branch names a commit that moves: a new revision
    # a second revision of one commit made before this rule takes its imports, sent again too
    with session_factory(api.settings.database_url)() as session:
        first = session.scalar(select(Revision).where(Revision.title == "i11"))
        twin = {"title": "i13", "sort_key": "13", "commit": sha, "repo": "", "branch": ""}
        session.add(Revision(component_id=first.component_id, order_key=first.order_key, **twin))
        session.commit()
    for status in (201, 200):
        kept = api.post("/api/v1/import/results", "ci", results("i13", sha))
        assert kept.status_code == status, kept.text


def test_an_import_takes_turns_with_a_verdict_being_stored(api: Api):
    """A trial's import into a revision being judged was refused 503 "deadlock detected":
    storing verdicts locks the component, then the revision's row (`db.lock_component`); the
    import locked the revision, then needed the component for its new series."""
    first = send_lnt(api, lnt_report())
    assert first.status_code == 201
    revision_id = first.json()["revision_id"]
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        component_id = session.get_one(Revision, revision_id).component_id
    locked, go = threading.Event(), threading.Event()
    outcome: list[object] = []

    def storing_verdicts() -> None:  # as `redline.worker.detection.store` does
        try:
            with session_factory(database_url)() as session:
                lock_component(session, component_id)
                locked.set()
                assert go.wait(30)
                session.execute(
                    update(Revision).where(Revision.id == revision_id).values(analyzed_at=utcnow())
                )
                session.commit()
            outcome.append("stored")
        except Exception as exc:  # the deadlock, had the import won it
            outcome.append(exc)

    report = lnt_report()
    report["tests"].append({"name": "new.exec", "execution_time": [2.0]})  # a new series
    _import_while_held(api, report, storing_verdicts, locked, go, outcome)
    answers = [o.status_code if hasattr(o, "status_code") else o for o in outcome]
    assert sorted(answers, key=str) == [201, "stored"], [getattr(o, "text", o) for o in outcome]


def test_an_import_takes_turns_with_a_commit_status_being_written(api: Api):
    """A review found the import's component lock (taken for the test above) deadlocked with a
    commit status: that locks the revision, then its delivery's row needs the component's. Both
    take the component's key-share lock before the revision's now."""
    report = lnt_report()
    report["run"]["git_sha"] = "a" * 40
    first = send_lnt(api, report)
    assert first.status_code == 201, first.text
    revision_id = first.json()["revision_id"]
    database_url = api.settings.database_url
    target = {"provider": "github", "api_url": "https://api.github.com", "repository": "o/r"}
    with session_factory(database_url)() as session:
        revision = session.get_one(Revision, revision_id)
        session.execute(
            update(Component)
            .where(Component.id == revision.component_id)
            .values(commit_status={**target, "token": "t"})
        )
        session.commit()
    reached, go = threading.Event(), threading.Event()
    outcome: list[object] = []

    def writing_a_status() -> None:
        def hold(held: Session, *_: object) -> None:  # its delivery's row about to be made
            if any(isinstance(row, Delivery) for row in held.new) and not reached.is_set():
                reached.set()
                assert go.wait(30)

        try:
            with session_factory(database_url)() as session:
                event.listen(session, "before_flush", hold)
                made = commit_status(session, revision_id)
                session.commit()
            outcome.append(len(made))
        except Exception as exc:  # the deadlock, had the status lost it
            outcome.append(exc)

    again = lnt_report(scale=2.0)  # a second machine's results of the revision
    again["run"]["git_sha"] = "a" * 40
    _import_while_held(api, again, writing_a_status, reached, go, outcome)
    answers = [o.status_code if hasattr(o, "status_code") else o for o in outcome]
    assert sorted(answers, key=str) == [1, 201], [getattr(o, "text", o) for o in outcome]


def _import_while_held(
    api: Api,
    report: dict,
    holder: Callable[[], None],
    holding: threading.Event,
    go: threading.Event,
    outcome: list[object],
) -> None:
    """``holder`` runs in a thread until it holds its locks (``holding``); then ``report`` is
    imported until it waits on a lock, ``go`` lets the holder finish, and both end; the
    import's answer joins ``outcome``."""
    worker = threading.Thread(target=holder)
    worker.start()
    assert holding.wait(30)
    importing = threading.Thread(target=lambda: outcome.append(send_lnt(api, report)))
    importing.start()
    for _ in range(600):
        if waiting_on_a_lock(api.settings.database_url):
            break
        importing.join(0.05)
    go.set()
    worker.join(30)
    importing.join(30)
