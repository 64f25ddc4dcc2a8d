"""The whole path on real Postgres, Redis, zenoh, a real Celery worker and real Chromium.

CI report → job → agent (checkout, build, run with monitor and recorder) → MCAP upload →
ingest → KS detection → confirmation runs on the agent → regression, CI verdict, API and trend
page. The example's history has a baseline, a revision that leaves the code's work alone, and
one doing three times the work per leg pair. The demo alarms on KS at a 50 % floor
(`demo.DEMO_DETECTION`) and confirms by re-running: with one execution per revision the same
code's CPU is bimodal on these VMs and now and then far off (a CI run flagged the unchanged
revision at +61 %), while the tripled work moves it by +60 % or more (+69 % to +113 % seen). No
floor parts them; the pairs of re-runs do.

Serial: it judges the component's CPU, which other tests' load would move.
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Iterator
from dataclasses import dataclass

import httpx
import pytest
from redline.commands import demo
from redline.commands.stack import Stack
from redline.detect.counters import is_cumulative
from redline.recording.format import canonical_params

from tests.support.pages import Watched, chromium
from tests.support.servers import Services, fresh_database

pytestmark = pytest.mark.serial

CPU = "cpu_percent"


@dataclass
class History:
    stack: Stack
    revisions: list[dict]
    base: demo.DemoRevision
    unchanged: demo.DemoRevision
    regressed: demo.DemoRevision


@pytest.fixture(scope="module")
def history(services: Services, tmp_path_factory: pytest.TempPathFactory) -> Iterator[History]:
    from redline.agent.network import free_port

    root = tmp_path_factory.mktemp("e2e")
    database_url, _ = fresh_database(services.database_url)
    saved = dict(os.environ)
    os.environ.update(
        REDLINE_DATABASE_URL=database_url,
        REDLINE_REDIS_URL=services.redis_url,
        REDLINE_QUEUE=f"e2e-{uuid.uuid4().hex[:8]}",
        # a pair run while something else loaded the host runs again a minute later, not five:
        # within the wait below
        REDLINE_QUIET_WAIT_S="60",
    )
    stack = Stack(root / "data", free_port())
    try:
        stack.start()
        repo = root / "objectbuilder-repo"
        base, unchanged, regressed = demo.make_history(repo)
        demo.submit(
            stack.url,
            stack.admin_token,
            stack.token("ci", "ci"),
            repo,
            [base, unchanged, regressed],
        )
        revisions = demo.wait_for_results(stack.url, print, timeout=600)
        yield History(stack, revisions, base, unchanged, regressed)
    finally:
        stack.stop()
        os.environ.clear()
        os.environ.update(saved)


def _cpu_changes(history: History, revision: str) -> list[dict]:
    """KS's verdicts on the component's own CPU (not host-wide counters, which other load
    moves), with what confirmation made of them."""
    return [
        d
        for d in httpx.get(
            f"{history.stack.url}/api/v1/components/objectbuilder/detections",
            params={"revision": revision, "method": "ks"},
        ).json()
        if d["series"]["counter"] == CPU and d["series"]["process"] == "objectbuilder"
    ]


def _verdict(history: History, revision: str) -> dict:
    url = f"{history.stack.url}/api/v1/components/objectbuilder/revisions/{revision}/verdict"
    return httpx.get(url).json()


def test_every_revision_runs_to_done_in_sort_key_order(history: History):
    titles = [r["title"] for r in history.revisions]
    assert titles == [history.base.title, history.unchanged.title, history.regressed.title]
    assert all(r["state"] == "done" for r in history.revisions), history.revisions


def test_tripled_work_is_confirmed_by_reruns_and_unchanged_code_raises_nothing(history: History):
    regressed = _cpu_changes(history, history.regressed.title)
    assert all(c["effect"] > 0 for c in regressed if c["flagged"]), json.dumps(regressed, indent=1)
    # At 8 legs the pairwise work dominates the component's CPU, so tripling it must show at
    # every rate; at 2 legs fixed per-message overhead hides much of it. One execution a
    # revision: the tripled work's +100 % or so shows anywhere from about +60 %; what must hold
    # is that it clears the demo's 50 % floor, is flagged, and the re-runs confirm it.
    heavy = [c for c in regressed if c["series"]["params"].get("legs") == 8]
    assert len(heavy) == 2, json.dumps(regressed, indent=1)
    assert all(c["flagged"] and c["effect"] > demo.DEMO_KS_FLOOR for c in heavy), json.dumps(
        heavy, indent=1
    )
    assert all(c["confirmation"] == "held" for c in heavy), json.dumps(heavy, indent=1)
    assert all(c["confirmation_reason"].startswith("confirmed by ") for c in heavy)
    assert all(c["regression_id"] is not None for c in heavy)
    gate = _verdict(history, history.regressed.title)
    assert gate["state"] == "done" and gate["regressions"] >= 2, gate
    # The unchanged revision may be flagged (one execution is that noisy), but what the pairs
    # of re-runs do not show is dropped: nothing at it alarms or fails CI.
    unchanged = _cpu_changes(history, history.unchanged.title)
    assert unchanged, "the unchanged revision was compared with its baseline"
    kept = [c for c in unchanged if c["flagged"] and c["confirmation"] != "dropped"]
    assert not kept, json.dumps(unchanged, indent=1)
    gate = _verdict(history, history.unchanged.title)
    assert gate["state"] == "done" and gate["regressions"] == 0, gate
    first = _cpu_changes(history, history.base.title)
    assert first and all(  # no baseline to compare with
        d["verdict"] == "not enough data" and d["baseline"] is None for d in first
    ), json.dumps(first, indent=1)


def test_confirmation_runs_stay_out_of_the_revisions_own_executions(history: History):
    detail = httpx.get(
        f"{history.stack.url}/api/v1/components/objectbuilder/revisions/{history.regressed.title}"
    ).json()
    # reported as `redline ci report` would: its message, and the hash its runs measured
    assert detail["message"] == history.regressed.subject
    assert detail["measured_commit"] == history.regressed.commit
    own = [job for job in detail["jobs"] if job["pair"] == 0]
    pairs = [job for job in detail["jobs"] if job["pair"] > 0]
    assert len(own) == 1 and own[0]["state"] == "done", detail["jobs"]
    # two agreeing pairs decide, the third is spared (cancelled as not needed) or ran
    assert {job["confirms"] for job in pairs} == {history.regressed.title}, detail["jobs"]
    assert len([job for job in pairs if job["state"] == "done"]) >= 2, detail["jobs"]
    # a pair the ones before it made unneeded never started (its baseline's run is on r2)
    baseline = httpx.get(
        f"{history.stack.url}/api/v1/components/objectbuilder/revisions/{history.unchanged.title}"
    ).json()
    spared = [
        job
        for job in [*pairs, *baseline["jobs"]]
        if job["confirms"] == history.regressed.title and job["reason"].startswith("not needed")
    ]
    assert all(job["attempts"] == 0 and job["execution"] is None for job in spared), spared
    # each ran the parameter sets with a suspected change: alone for a change in CPU or a round
    # trip, else the suite as far as the last of them; never the test cases after them
    changes = httpx.get(
        f"{history.stack.url}/api/v1/components/objectbuilder/detections",
        params={"revision": history.regressed.title},
    ).json()
    flagged = {  # the changes that were suspected, which the pairs were queued for
        (c["series"]["case"], canonical_params(c["series"]["params"]))
        for c in changes
        if c["flagged"] and c["confirmation"]
    }
    ran = _sets_run(history, [job["id"] for job in pairs if job["state"] == "done"])
    assert flagged and flagged <= ran, (ran, flagged)
    suspects = [c["series"]["counter"] for c in changes if c["flagged"] and c["confirmation"]]
    if not any(map(is_cumulative, suspects)):  # nothing before the flagged sets ran again
        assert ran == flagged, (ran, flagged, suspects)
    # the round-trip case comes after the CPU case: unless it was flagged, it did not run again
    if all(case != "locate" for case, _ in flagged):
        assert all(case != "locate" for case, _ in ran), (ran, flagged)


def _sets_run(history: History, jobs: list[int]) -> set[tuple[str, str]]:
    """(case, parameter set) of the measured phases of these jobs' executions."""
    from redline.server.models import Execution, Series, Summary
    from sqlalchemy import create_engine, select
    from sqlalchemy.orm import Session

    engine = create_engine(os.environ["REDLINE_DATABASE_URL"])
    try:
        with Session(engine) as session:
            rows = session.execute(
                select(Series.case, Series.params)
                .join(Summary, Summary.series_id == Series.id)
                .join(Execution, Execution.id == Summary.execution_id)
                .where(Execution.job_id.in_(jobs), Series.process == "objectbuilder")
                .distinct()
            )
            return {(case, params) for case, params in rows}
    finally:
        engine.dispose()


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    with chromium() as launched:
        yield launched


@pytest.mark.browser
def test_trend_page_marks_the_regression_in_chromium(history: History, browser):
    title = "legs_and_rate/steady objectbuilder.cpu_percent"
    watched = Watched(browser, history.stack.url)
    watched.visit(f"{history.stack.url}/components/objectbuilder")
    page = watched.page
    page.wait_for_selector(".js-plotly-plot .scatterlayer .trace", timeout=30_000, state="attached")
    chart = page.locator(f'.chart[aria-label="{title}"]')
    chart.scroll_into_view_if_needed()
    drawn = "el => el.data !== undefined"
    page.wait_for_function(drawn, arg=chart.element_handle(), timeout=30_000)
    marks = chart.evaluate(
        """el => el.data.filter(t => (t.name || '').startsWith('change'))
               .flatMap(t => t.x.map((x, i) => [t.name, x, t.text[i]]))"""
    )
    assert not watched.errors, watched.errors
    confirmed = [(x, text) for name, x, text in marks if name == "change (confirmed)"]
    heavy = [x for x, text in confirmed if "legs=8," in text]
    assert len(heavy) == 2 and set(heavy) == {history.regressed.title}, marks
    # a flag of the unchanged revision, if any, is drawn as not confirmed
    assert all(
        name == "change (not confirmed)" for name, x, _ in marks if x == history.unchanged.title
    ), marks


@pytest.mark.browser
def test_every_page_of_the_demo_loads_clean(history: History, browser):
    """The pages on the demo's own data (docs/ui.md's screenshots, with REDLINE_SCREENSHOTS)."""
    base, regressed = history.stack.url, history.regressed.title
    api = f"{base}/api/v1/components/objectbuilder"
    flagged = [
        d
        for d in httpx.get(f"{api}/detections", params={"revision": regressed}).json()
        if d["flagged"] and d["series"]["counter"] == CPU
    ]
    assert flagged, "the tripled work has a flagged detection to explain"
    execution = httpx.get(f"{api}/revisions/{regressed}").json()["jobs"][0]["execution"]["id"]
    pages = {
        "demo-home": "/",
        "demo-component": "/components/objectbuilder?process=objectbuilder&counter=cpu_percent",
        "demo-revision": f"/components/objectbuilder/revisions/{regressed}",
        "demo-compare": (
            f"/components/objectbuilder/compare?base={history.base.title}&candidate={regressed}"
        ),
        "demo-regressions": "/regressions",
        "demo-why-flagged": f"/detections/{flagged[0]['id']}",
        "demo-execution": f"/executions/{execution}",
    }
    watched = Watched(browser, base)
    for name, path in pages.items():
        watched.visit(base + path, name)
        if name in ("demo-component", "demo-compare", "demo-why-flagged", "demo-execution"):
            assert watched.first_chart_traces() > 0, name
    assert not watched.errors, watched.errors
    assert not watched.foreign, watched.foreign
