"""The whole path on real Postgres, Redis, zenoh, a real Celery worker and real Chromium.

CI report → job → agent (checkout, build, run with monitor and recorder) → MCAP upload →
ingest → KS detection → API and trend page. The example's history has a baseline, a revision
that leaves the code's work alone, and one doing three times the work per leg pair. The demo
configures KS's floor at 50 % (`demo.DEMO_KS_FLOOR`): with one execution per revision, the same
code's CPU is bimodal on these VMs (-18.6 % once flagged the unchanged revision at the 10 %
default), while the tripled work moves it by +60 % or more (+69 % to +113 % seen).

Serial: it judges the component's CPU, which other tests' load would move.
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
from redline.commands import demo
from redline.commands.stack import Stack

from tests.support.servers import Services, fresh_database

pytestmark = pytest.mark.serial

CPU = "cpu_percent"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]


@dataclass
class History:
    stack: Stack
    revisions: list[dict]
    changes: list[dict]
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
        changes = httpx.get(f"{stack.url}/api/v1/components/objectbuilder/changes").json()
        yield History(stack, revisions, changes, base, unchanged, regressed)
    finally:
        stack.stop()
        os.environ.clear()
        os.environ.update(saved)


def _cpu_changes(changes: list[dict], revision: str) -> list[dict]:
    """KS results on the component's own CPU (not host-wide counters, which other load moves)."""
    return [
        c
        for c in changes
        if c["revision"] == revision
        and c["series"]["counter"] == CPU
        and c["series"]["process"] == "objectbuilder"
    ]


def test_every_revision_runs_to_done_in_sort_key_order(history: History):
    titles = [r["title"] for r in history.revisions]
    assert titles == [history.base.title, history.unchanged.title, history.regressed.title]
    assert all(r["state"] == "done" for r in history.revisions), history.revisions


def test_tripled_work_is_flagged_by_ks_and_unchanged_code_is_not(history: History):
    regressed = _cpu_changes(history.changes, history.regressed.title)
    assert all(c["effect"] > 0 for c in regressed if c["flagged"]), json.dumps(regressed, indent=1)
    # At 8 legs the pairwise work dominates the component's CPU, so tripling it must show at
    # every rate; at 2 legs fixed per-message overhead hides much of it.
    heavy = [c for c in regressed if c["series"]["params"].get("legs") == 8]
    assert len(heavy) == 2, json.dumps(regressed, indent=1)
    # One execution a revision: the same code's CPU moves 8-20 % between executions on these
    # VMs (docs/detection.md, "A quiet host"), so the tripled work's +100 % or so shows anywhere
    # from about +60 %; what must hold is that it clears the demo's 50 % floor and is flagged.
    assert all(c["flagged"] and c["effect"] > demo.DEMO_KS_FLOOR for c in heavy), json.dumps(
        heavy, indent=1
    )
    unchanged = _cpu_changes(history.changes, history.unchanged.title)
    assert unchanged, "the unchanged revision was compared with its baseline"
    assert not [c for c in unchanged if c["flagged"]], json.dumps(unchanged, indent=1)
    assert not _cpu_changes(history.changes, history.base.title)  # no baseline to compare with


@pytest.mark.browser
def test_trend_page_marks_the_regression_in_chromium(history: History, tmp_path: Path):
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: `python3 run.py test` installs Debian's chromium")
    title = "legs_and_rate/steady objectbuilder.cpu_percent"
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_FLAGS)
        page = browser.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.goto(f"{history.stack.url}/components/objectbuilder")
        page.wait_for_selector(
            ".js-plotly-plot .scatterlayer .trace", timeout=30_000, state="attached"
        )
        page.screenshot(path=str(tmp_path / "objectbuilder.png"), full_page=True)
        print(f"screenshot: {tmp_path / 'objectbuilder.png'}")
        chart = page.locator(f'.chart[aria-label="{title}"]')
        chart.scroll_into_view_if_needed()
        page.wait_for_function(
            "el => el.data !== undefined", arg=chart.element_handle(), timeout=30_000
        )
        marks = chart.evaluate(
            """el => el.data.filter(t => (t.name || '').startsWith('change'))
                   .flatMap(t => t.x.map((x, i) => [x, t.text[i]]))"""
        )
        browser.close()
    assert not errors, errors
    heavy = [x for x, text in marks if "legs=8," in text]
    assert len(heavy) == 2 and set(heavy) == {history.regressed.title}, marks
