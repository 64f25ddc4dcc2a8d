"""`redline ci wait` (the real command, in its own process) against a live server on real Postgres:
its exit codes, the JUnit XML it writes, and the verdict endpoints behind it."""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pytest
import typer
from redline.cli import ci_cmd
from redline.server.db import session_factory
from redline.server.models import Job, JobState, Regression, Revision
from redline.server.schemas.components import ComponentCreate
from redline.server.services.components import create_component
from sqlalchemy import select
from typer.testing import CliRunner

from tests.support.api import api_with
from tests.support.git import GIT
from tests.support.history import add_executions, cpu_history, ingest_and_detect
from tests.support.receivers import flaky_proxy
from tests.support.servers import live_server

REDLINE = str(Path(sys.executable).parent / "redline")
#: r6 rose by 40 %: a change for the worse; r1 has no baseline; r3 is like its neighbours
CPUS = [10.0] * 5 + [14.0, 14.0]


@pytest.fixture(scope="module")
def server(services, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ci")
    with api_with(services, tmp, read_access="token") as api:
        with session_factory(api.settings.database_url)() as session:
            executions = cpu_history(session, tmp, CPUS, config={"methods": ["ks"]})
        ingest_and_detect(api.settings.database_url, executions)
        with session_factory(api.settings.database_url)() as session:
            _busy_baseline(session, api.settings.database_url, tmp)
        read = api.tokens["read"]["Authorization"].removeprefix("Bearer ")
        with live_server(api.settings) as url:
            yield url, read, api


def _busy_baseline(session, database_url: str, tmp: Path) -> None:
    """Component "busy": b1 measured while the host was busy, then b2 at four times its CPU on
    a quiet host; b1's fresh run, which b2's verdict waits for, fails (the host went away)."""
    create_component(session, ComponentCreate(name="busy", executions=1))
    rng = np.random.default_rng(3)
    for title, cpu, load in (("b1", 10.0, 90.0), ("b2", 40.0, None)):
        runs = [{"cpu": rng.normal(cpu, cpu / 20, 60)}]
        executions = add_executions(session, tmp, "busy", title, title[1:], runs, host_percent=load)
        ingest_and_detect(database_url, executions)
    session.expire_all()
    (fresh,) = session.scalars(select(Job).where(Job.remeasures_job_id.is_not(None)))
    fresh.state, fresh.reason = JobState.failed, "the host went away"
    session.commit()


def wait(
    server, *args: str, token: str | None = None, via: str | None = None
) -> subprocess.CompletedProcess:
    """`redline ci wait` against the server (or ``via``, a proxy in front of it)."""
    url, read, _ = server
    url = via or url
    env = {"PATH": "/usr/bin:/bin", "REDLINE_TOKEN": read if token is None else token}
    return subprocess.run(
        [REDLINE, "ci", "wait", "--server", url, "--component", "builder", "--poll", "0.2", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )


def test_a_change_for_the_worse_fails_with_1_and_a_junit_failure(server, tmp_path):
    out = tmp_path / "junit.xml"
    done = wait(server, "--revision", "r6", "--junit", str(out))
    assert done.returncode == 1, done.stderr
    assert "cpu +" in done.stdout and "1 change(s) for the worse" in done.stdout
    # said on the console as in the JUnit file (a trial's table showed a suspected change as
    # plainly failed)
    assert re.search(r"cpu \+[0-9.]+ % \(suspected: not confirmed yet\)", done.stdout), done.stdout
    suite = ElementTree.parse(out).getroot()
    assert (suite.get("tests"), suite.get("failures"), suite.get("skipped")) == ("1", "1", "0")
    failure = suite.find("testcase/failure")
    assert failure is not None and failure.get("type") == "regression"
    assert "cpu" in failure.get("message", "") and "ks" in failure.get("message", "")
    assert "confirmation: suspected" in failure.get("message", "")
    # --fail-on none: the same verdict, reported, never failing
    assert wait(server, "--revision", "r6", "--fail-on", "none").returncode == 0


def test_a_proxys_502_while_the_server_restarts_is_waited_for_not_read_as_a_change(
    server, tmp_path
):
    """A review: a 502 from the proxy fetching the JUnit file raised, and Python's exit 1 said
    "a change" of an unchanged commit; a 502 while polling was exit 2 at once. The JUnit file
    is fetched on its own only from a server that does not send it with the verdict (the proxy
    drops the verdict's `junit` parameter: a server from before it)."""
    out = tmp_path / "junit.xml"
    with flaky_proxy(server[0]) as proxy:
        proxy.answers = {"/verdict": [502, 503]}
        done = wait(server, "--revision", "r3", "--junit", str(out), via=proxy.url)
        assert done.returncode == 0, done.stderr
        assert done.stderr.count("not reachable (HTTP 50") == 2, done.stderr
        assert not [p for p in proxy.seen if "/junit" in p]  # it came with the verdict
        # once, with the verdict that settled: not built by the server at every poll
        assert [p for p in proxy.seen if "junit=" in p] == [proxy.seen[-1]], proxy.seen
        suite = ElementTree.parse(out).getroot()
        assert (suite.get("tests"), suite.get("failures"), suite.get("errors")) == ("1", "0", "0")
        proxy.seen.clear()
        proxy.dropped, proxy.answers = {"junit"}, {"/junit": [502, 504]}
        out.unlink()
        older = wait(server, "--revision", "r3", "--junit", str(out), via=proxy.url)
        assert older.returncode == 0, older.stderr
        assert older.stderr.count("not reachable (HTTP 50") == 2, older.stderr
        assert [p.split("?")[0].rsplit("/", 1)[1] for p in proxy.seen].count("junit") == 3
        assert ElementTree.parse(out).getroot().get("failures") == "0"
        # a JUnit file the server refuses is no pass and no change: exit 2, said in the file
        proxy.answers = {"/junit": [500]}
        refused = wait(server, "--revision", "r6", "--junit", str(out), via=proxy.url)
    assert refused.returncode == 2, refused.stderr
    said = "the verdict came, but not its JUnit file: HTTP 500"
    assert said in refused.stderr and said in out.read_text()


@contextmanager
def _r6_made_pending(api) -> Iterator[Callable[[bool], None]]:
    """A switch that makes r6's verdict pending (as a result ingested for it would) or settled
    again as it was; settled again at the end."""
    factory = session_factory(api.settings.database_url)

    def r6(session) -> Revision:
        return session.scalars(select(Revision).where(Revision.title == "r6")).one()

    with factory() as session:
        saved = r6(session).analyzed_at

    def pending(yes: bool) -> None:
        with factory() as session:
            r6(session).analyzed_at = None if yes else saved
            session.commit()

    try:
        yield pending
    finally:
        pending(False)


def test_the_junit_file_and_the_exit_code_are_of_one_reading_of_the_verdict(server, tmp_path):
    """A review: the verdict and its JUnit file were read in two requests, and a result judged
    between them made the file say one thing and the exit code another. Here r6 is made pending
    again (a result ingested for it) as soon as the file is asked for on its own: its file must
    still be the done verdict's, failed as the exit code says."""
    out = tmp_path / "junit.xml"
    with _r6_made_pending(server[2]) as pending, flaky_proxy(server[0]) as proxy:
        proxy.before = {"/junit": lambda: pending(True)}
        done = wait(server, "--revision", "r6", "--junit", str(out), via=proxy.url)
    assert done.returncode == 1, done.stderr
    suite = ElementTree.parse(out).getroot()
    assert suite.get("failures") == "1" and suite.find("testcase/skipped") is None


def test_a_verdict_pending_again_once_settled_is_polled_without_its_junit_xml(server, tmp_path):
    """r6's verdict settles, then reads pending again when asked for with its JUnit XML (a
    result came in meanwhile) for two polls: `ci wait` polls without the XML again (the server
    would build it at every poll), and reads it once more when the verdict settles again."""
    out = tmp_path / "junit.xml"
    polls: list[str] = []  # the polls since the verdict first read pending again

    with _r6_made_pending(server[2]) as pending, flaky_proxy(server[0]) as proxy:

        def pending_for_two_polls() -> None:
            if polls or "junit=" in proxy.seen[-1]:
                polls.append(proxy.seen[-1])
                pending(len(polls) <= 3)

        proxy.before = {"/verdict": pending_for_two_polls}
        done = wait(server, "--revision", "r6", "--junit", str(out), via=proxy.url)
    assert done.returncode == 1, done.stderr
    asked = [p for p in proxy.seen if p.split("?")[0].endswith("/verdict")]
    with_xml = [i for i, p in enumerate(asked) if "junit=" in p]
    assert len(with_xml) == 2 and with_xml[1] - with_xml[0] >= 3, asked
    assert ElementTree.parse(out).getroot().get("failures") == "1"


def test_no_change_passes_and_no_baseline_is_skipped_with_its_reason(server, tmp_path):
    out = tmp_path / "junit.xml"
    assert wait(server, "--revision", "r3", "--junit", str(out)).returncode == 0
    suite = ElementTree.parse(out).getroot()
    assert (suite.get("failures"), suite.get("skipped")) == ("0", "0")
    first = wait(server, "--revision", "r1", "--junit", str(out))
    assert first.returncode == 0, first.stderr
    skipped = ElementTree.parse(out).getroot().find("testcase/skipped")
    assert skipped is not None and "not enough data" in skipped.get("message", "")


def test_a_later_revision_is_told_of_the_regression_still_open_before_it(server, tmp_path):
    """A trial's unchanged commits after a suspected regression each passed with exit 0 and no
    word that the code they carried was suspected slower (2026-12-06): r7 is told of r6's, in
    the table, the JSON, the JUnit file and its page, and no longer once it is triaged as
    fixed; r3,
    before it, is told of none."""
    _, _, api = server
    out = tmp_path / "junit.xml"
    later = wait(server, "--revision", "r7", "--junit", str(out))
    assert later.returncode == 0, later.stdout + later.stderr
    said = re.search(
        r"1 regression\(s\) still open before this revision.*\n  #(\d+) suspected, triage new: "
        r"after r5, shows at r6: .*cpu .*\+\d+\.\d % at r6  http://\S+/regressions/(\d+)",
        later.stdout,
    )
    assert said is not None and said[1] == said[2], later.stdout
    number = int(said[1])
    suite_out = ElementTree.parse(out).getroot().find("system-out")
    assert suite_out is not None and f"regression #{number} still open" in (suite_out.text or "")
    verdict = api.client.get(
        "/api/v1/components/builder/revisions/r7/verdict", headers=api.headers("read")
    ).json()
    assert verdict["regressions"] == 0 and verdict["open_before_total"] == 1
    assert verdict["open_before"][0]["page"] == f"/regressions/{number}"
    page = api.client.get("/components/builder/revisions/r7", headers=api.headers("read"))
    assert re.search(
        rf'<div id="open-before"><p>1 regression of builder still open before this revision.*'
        rf'<a href="/regressions/{number}">#{number}</a>',
        page.text,
        re.S,
    ), page.text
    assert (
        "open-before"
        not in api.client.get("/components/builder/revisions/r3", headers=api.headers("read")).text
    )
    before = wait(server, "--revision", "r3", "--junit", str(out))
    assert "still open" not in before.stdout and ElementTree.parse(out).find("system-out") is None
    own = wait(server, "--revision", "r6")  # its own regression is its verdict, not before it
    assert own.returncode == 1 and "still open" not in own.stdout, own.stdout
    triage = f"/api/v1/components/builder/regressions/{number}"
    try:
        fixed = api.client.patch(triage, json={"state": "fixed"}, headers=api.headers("triage"))
        assert fixed.status_code == 200, fixed.text
        assert "still open" not in wait(server, "--revision", "r7").stdout
    finally:  # the module's other tests see the regression as they found it
        api.client.patch(triage, json={"state": "new"}, headers=api.headers("triage"))
    # one its re-runs dropped (not confirmed) or a re-analysis withdrew is not open either
    with session_factory(api.settings.database_url)() as session:
        regression = session.get_one(Regression, number)
        regression.confirmation = "not_confirmed"
        session.commit()
        try:
            assert "still open" not in wait(server, "--revision", "r7").stdout
        finally:
            regression.confirmation = "suspected"
            session.commit()


def test_a_verdict_the_busy_host_left_undecided_exits_4_never_0(server, tmp_path):
    """A trial from outside saw a 4x regression pass where every run of the baseline had been
    disturbed (2026-11-24): exit 0 with skipped test cases."""
    out = tmp_path / "junit.xml"
    done = wait(server, "--component", "busy", "--revision", "b2", "--junit", str(out))
    assert done.returncode == 4, (done.stdout, done.stderr)
    assert "undecided" in done.stdout and "host busy" in done.stderr  # the case's own reason
    suite = ElementTree.parse(out).getroot()
    assert (suite.get("errors"), suite.get("skipped")) == ("1", "0")
    assert suite.get("tests") == str(len(suite.findall("testcase")))  # counted once, not twice
    assert "host busy" in suite.find("testcase/error").get("message", "")
    assert (
        wait(server, "--component", "busy", "--revision", "b2", "--fail-on", "none").returncode == 0
    )


def test_bad_input_and_a_timeout_exit_2_naming_the_cause(server):
    unknown = wait(server, "--revision", "r1", "--component", "nobody")
    assert unknown.returncode == 2 and "unknown component 'nobody'" in unknown.stderr
    refused = wait(server, "--revision", "r1", token="rl_not-a-token")
    assert refused.returncode == 2 and "refused the token" in refused.stderr
    early = wait(server, "--revision", "nosuch", "--timeout", "2")  # said at once, not after
    assert early.returncode == 2, early.stderr
    assert "has no revision 'nosuch' yet: waiting up to 2 s for it" in early.stderr
    assert "no verdict within 2 s: still waiting for the revision to be reported" in early.stderr
    bad = wait(server, "--revision", "r1", "--fail-on", "sometimes")
    assert bad.returncode == 2 and "fail-on" in bad.stderr
    # names no address can carry, said as such (a trial was told "Not Found")
    for option, name in (("--revision", ".."), ("--revision", ""), ("--component", "../x")):
        args = ("--revision", "r1", "--component", "builder", option, name)
        odd = wait(server, *args)
        assert odd.returncode == 2, odd.stderr
        assert f"{option} {name!r}: not a name Redline gives anything" in odd.stderr
    wrong = subprocess.run(
        [REDLINE, "ci", "wait", "--server", server[0] + "/nothing-here", "--component", "builder",
         "--revision", "r1"],
        capture_output=True, text=True, timeout=60, env={"PATH": "/usr/bin:/bin"},
    )  # fmt: skip
    assert wrong.returncode == 2 and "is --server the root URL of the Redline server?" in (
        wrong.stderr
    )
    _, _, api = server
    api.revision("r8", "0008")  # queued, and no host to run it
    kept = Path(api.settings.storage_dir).parent / "late.xml"
    late = wait(server, "--revision", "r8", "--timeout", "2", "--junit", str(kept))
    made = kept.parent / "reports" / "of-r8" / "late.xml"  # a missing folder is made
    assert wait(server, "--revision", "r8", "--timeout", "1", "--junit", str(made)).returncode == 2
    assert "no verdict within 1 s" in made.read_text()
    # a revision never reported, and a refused token: the JUnit file says so too (a trial's
    # CI step found none to keep)
    for args, said in (
        (("--revision", "neverreported", "--timeout", "1"), "no verdict within 1 s"),
        (("--revision", "..", "--timeout", "1"), "not a name Redline gives anything"),
    ):
        never = kept.parent / f"never-{len(said)}.xml"
        assert wait(server, *args, "--junit", str(never)).returncode == 2
        assert said in never.read_text()
    assert late.returncode == 2
    assert "no verdict within 2 s" in late.stderr and "performance host" in late.stderr
    error = ElementTree.parse(kept).getroot().find("testcase/error")
    assert error is not None and "no verdict within 2 s" in error.get("message", "")
    # refused before any waiting: a JUnit path that cannot be written, a server that is no URL
    started = time.monotonic()
    under_a_file = kept / "dir" / "x.xml"  # `late.xml` is a file
    nowhere = wait(server, "--revision", "r8", "--junit", str(under_a_file))
    assert nowhere.returncode == 2, nowhere.stderr
    assert f"no folder {kept / 'dir'} can be made: Not a directory" in nowhere.stderr
    assert time.monotonic() - started < 30
    url = subprocess.run(
        [REDLINE, "ci", "wait", "--server", "notaurl", "--component", "c", "--revision", "r"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert url.returncode == 2 and "not an http:// or https:// URL" in url.stderr


def test_failed_jobs_exit_3(server):
    _, _, api = server
    api.revision("r9", "0009")
    with session_factory(api.settings.database_url)() as session:
        revision = session.query(Revision).filter_by(title="r9").one()
        jobs = session.query(Job).filter_by(revision_id=revision.id).all()
        second = max(job.execution_index for job in jobs) + 1  # a second execution, as 2 asks
        session.add(Job(revision_id=revision.id, execution_index=second, labels=[]))
        session.flush()
        for job in session.query(Job).filter_by(revision_id=revision.id):
            job.state, job.reason = JobState.failed, "build failed"
        session.commit()
    done = wait(
        server,
        "--revision",
        "r9",
        "--junit",
        str(Path(server[2].settings.storage_dir).parent / "r9.xml"),
    )
    assert done.returncode == 3 and "build failed" in done.stderr, done.stderr
    # one line for one reason, whatever the jobs that failed with it; and no table of counts,
    # which read as a verdict ("0 change(s) for the worse ...") where there is none
    assert done.stderr.count("build failed") == 1, done.stderr
    assert "change(s) for the worse" not in done.stdout, done.stdout
    suite = ElementTree.parse(Path(server[2].settings.storage_dir).parent / "r9.xml").getroot()
    assert suite.get("errors") == "1"  # not an empty, green report
    assert "build failed" in suite.find("testcase/error").get("message", "")


def test_a_cases_parameters_are_an_object_as_everywhere_else(server):
    """A trial's CI script read "parameters": "{\\"legs\\":2}" (JSON text inside JSON) from the
    verdict and "params": {"legs": 2} from the series."""
    import httpx

    url, read, _ = server
    answer = httpx.get(
        f"{url}/api/v1/components/builder/revisions/r6/verdict",
        headers={"Authorization": f"Bearer {read}"},
    )
    cases = answer.json()["cases"]
    assert cases and all(isinstance(case["parameters"], dict) for case in cases), cases
    junit = httpx.get(
        f"{url}/api/v1/components/builder/revisions/r6/junit",
        headers={"Authorization": f"Bearer {read}"},
    ).text
    names = [t.get("name") for t in ElementTree.fromstring(junit).iter("testcase")]
    # JUnit names are kept as they were (CI systems track tests by name): canonical JSON
    expected = [
        f"{c['phase']} {json.dumps(c['parameters'], sort_keys=True, separators=(',', ':'))}"
        for c in cases
    ]
    assert sorted(names) == sorted(expected), (names, expected)


def _git(tree: Path, *args: str) -> str:
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tree)}
    done = subprocess.run([*GIT, *args], cwd=tree, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_ci_report_reports_head_and_ci_wait_waits_for_it_by_default(server, tmp_path):
    """CI reported with curl and a here-document (docs/ci.md); a trial asked for a command."""
    url, _, api = server
    with session_factory(api.settings.database_url)() as session:
        create_component(
            session,
            ComponentCreate(name="hashed", repo="https://git.example/hashed.git", suite="p.toml"),
        )
    tree = tmp_path / "tree"
    tree.mkdir()
    _git(tree, "init", "-q")
    (tree / "a.txt").write_text("a\n")
    _git(tree, "add", "a.txt")
    _git(tree, "commit", "-qm", "Speed up the hash\n\nA longer body.")
    full, when = _git(tree, "log", "-1", "--format=%H %ct").split()
    ci = api.tokens["ci"]["Authorization"].removeprefix("Bearer ")
    env = {"PATH": "/usr/bin:/bin", "REDLINE_TOKEN": ci}

    def redline(*args: str, cwd: Path = tree) -> subprocess.CompletedProcess:
        command = [REDLINE, "ci", *args, "--server", url, "--component", "hashed"]
        return subprocess.run(command, capture_output=True, text=True, env=env, cwd=cwd)

    done = redline("report")
    assert done.returncode == 0, done.stderr
    assert done.stdout == f"{full[:12]}\n" and "reported: 1 job(s) queued" in done.stderr
    assert "warning" not in done.stderr  # no remote: nothing to compare
    with session_factory(api.settings.database_url)() as session:
        revision = session.scalar(select(Revision).where(Revision.title == full[:12]))
        assert revision is not None
        assert (revision.commit, revision.sort_key) == (full, when)
        assert revision.message.startswith("Speed up the hash")
    again = redline("report")  # a re-run pipeline
    assert again.returncode == 0 and "reported before with this commit" in again.stderr
    assert "not applied" not in again.stderr
    # a trial reported from another checkout, and its jobs failed minutes later: the work
    # tree's remotes are compared with the component's repository, credentials left out
    _git(tree, "remote", "add", "origin", "https://ci-token:s3cret@git.example/other.git")
    wrong = redline("report")
    assert wrong.returncode == 0, wrong.stderr
    assert (
        "warning: this work tree's remotes (git.example/other) are not the component's "
        "repository (git.example/hashed)"
    ) in wrong.stderr, wrong.stderr
    _git(tree, "remote", "add", "mirror", "git@git.example:Hashed.git")  # the same, spelt so
    assert "warning" not in redline("report").stderr
    _git(tree, "remote", "remove", "mirror")
    _git(tree, "remote", "set-url", "origin", "https://ci-token:s3cret@git.example/hashed.git")
    assert "warning" not in redline("report").stderr
    # a title or sort key given again is not applied, and it says so (a trial got the old
    # title back and no word)
    retitled = redline("report", "--title", "mytitle", "--sort-key", "12345")
    assert retitled.returncode == 0 and retitled.stdout == f"{full[:12]}\n", retitled.stderr
    assert (
        "--title and --sort-key not applied: a revision keeps its first report's title and sort "
        f"key (an admin corrects a sort key: PATCH /api/v1/components/hashed/revisions/{full[:12]})"
    ) in retitled.stderr, retitled.stderr
    waited = redline("wait", "--timeout", "1", "--poll", "0.2")  # HEAD's revision: no verdict yet
    assert waited.returncode == 2 and "still waiting for" in waited.stderr, waited.stderr
    assert "has no revision" not in waited.stderr
    # a commit named as git names it is sent as its full id, and the title printed is the
    # revision's, also when this report gave another (a trial's three reports of HEAD: a 422
    # for HEAD~1, a 409 for a branch's name, and a title that named nothing)
    (tree / "b.txt").write_text("b\n")
    _git(tree, "add", "b.txt")
    _git(tree, "commit", "-qm", "Second")
    _git(tree, "branch", "release", full)
    for named in (["--commit", "HEAD~1"], ["--commit", "release"], ["--title", full]):
        named = ["--commit", full, *named] if named[0] == "--title" else named
        done = redline("report", *named)
        assert done.returncode == 0, (named, done.stderr)
        assert done.stdout == f"{full[:12]}\n", (named, done.stdout)
    # a branch named with a title and sort key is sent as its hash too: the server takes no
    # other name for a commit (a fifth trial's branch, reported under a new title, measured
    # the commit of a revision that had failed CI again, and turned it green)
    done = redline("report", "--commit", "release", "--title", "t2", "--sort-key", "5")
    assert done.returncode == 0 and done.stdout == f"{full[:12]}\n", done.stderr
    refused = redline("report", "--commit", "a b", "--title", "t", "--sort-key", "1")
    assert refused.returncode == 2 and "cannot read commit 'a b' here" in refused.stderr
    assert "--commit as its hash" in refused.stderr, refused.stderr

    option = redline("report", "--commit", f"--output={tmp_path / 'written'}")
    assert option.returncode == 2 and "not a commit" in option.stderr, option.stderr
    assert not (tmp_path / "written").exists()
    outside = redline("report", cwd=tmp_path)  # not a work tree, and no --commit
    assert outside.returncode == 2 and "git work tree" in outside.stderr, outside.stderr
    junit = tmp_path / "head.xml"
    outside = redline("wait", "--junit", str(junit), cwd=tmp_path)  # nor a --revision
    assert outside.returncode == 2, outside.stderr
    assert outside.stderr.startswith("redline ci wait: cannot read commit 'HEAD' here")
    assert "(--revision)" in outside.stderr and "git work tree" in junit.read_text()
    bad_url = tmp_path / "url.xml"
    done = subprocess.run(
        [REDLINE, "ci", "wait", "--server", "ftp://x", "--component", "hashed", "--revision",
         "r1", "--junit", str(bad_url)], capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert done.returncode == 2 and "not an http:// or https:// URL" in bad_url.read_text()
    env["REDLINE_TOKEN"] = "rl_forged"
    refused = redline("report")
    assert refused.returncode == 2 and "HTTP 401" in refused.stderr, refused.stderr
    assert "no token was given" not in refused.stderr  # one was, and it was refused
    env["REDLINE_TOKEN"] = ""  # none at all: said how to give one (a trial read only the 401)
    for command in ("report", "wait"):
        bare = redline(command)
        said = " ".join(bare.stderr.split())
        assert bare.returncode == 2 and "no token was given: set REDLINE_TOKEN" in said, said


@pytest.mark.timeout(60)  # without the give-up it would wait its whole hour
def test_ci_wait_gives_up_on_a_server_it_never_reached(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
):
    """A wrong --server is said after APPEAR_S (2 minutes), not after the whole --timeout (an
    hour by default), in the JUnit file too."""
    with socket.socket() as unused:  # a port nobody listens on: bound, never listening
        unused.bind(("127.0.0.1", 0))
        port = unused.getsockname()[1]
        monkeypatch.setattr(ci_cmd, "APPEAR_S", 0.5)
        junit = tmp_path / "redline.xml"
        alone = typer.Typer()
        alone.command()(ci_cmd.wait)
        done = CliRunner().invoke(
            alone,
            ["--server", f"http://127.0.0.1:{port}", "--component", "c",
             "--revision", "r1", "--timeout", "3600", "--poll", "0.1", "--junit", str(junit)],
            env={"REDLINE_TOKEN": ""},
        )  # fmt: skip
    assert done.exit_code == 2, done.output
    said = " ".join(done.output.split())
    assert "not reachable (ConnectError); trying again" in said
    assert f"the server at http://127.0.0.1:{port} was not reached in" in said
    assert "is --server right?" in junit.read_text()
