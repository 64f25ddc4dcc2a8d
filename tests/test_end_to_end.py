"""The whole path on real Postgres, Redis, zenoh, a real Celery worker and real Chromium.

CI report → job → agent (checkout, build, run with monitor and recorder) → MCAP upload →
ingest → KS detection → API and trend page. The example's history has a baseline, a revision
that leaves the code's work alone, and one doing three times the work per leg pair.
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

from redline.server import demo
from redline.server.stack import Stack
from tests.conftest import Services, fresh_database

pytestmark = pytest.mark.integration

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
    os.environ.update(REDLINE_DATABASE_URL=database_url, REDLINE_REDIS_URL=services.redis_url,
                      REDLINE_QUEUE=f"e2e-{uuid.uuid4().hex[:8]}")
    stack = Stack(root / "data", free_port())
    try:
        stack.start()
        repo = root / "objectbuilder-repo"
        base, unchanged, regressed = demo.make_history(repo)
        demo.submit(stack.url, stack.admin_token, stack.token("ci", "ci"), repo,
                    [base, unchanged, regressed])
        revisions = demo.wait_for_results(stack.url, print, timeout=600)
        changes = httpx.get(f"{stack.url}/api/v1/components/objectbuilder/changes").json()
        yield History(stack, revisions, changes, base, unchanged, regressed)
    finally:
        stack.stop()
        os.environ.clear()
        os.environ.update(saved)


def _cpu_changes(changes: list[dict], revision: str) -> list[dict]:
    return [c for c in changes if c["revision"] == revision and c["series"]["counter"] == CPU]


def test_every_revision_runs_to_done_in_sort_key_order(history: History):
    titles = [r["title"] for r in history.revisions]
    assert titles == [history.base.title, history.unchanged.title, history.regressed.title]
    assert all(r["state"] == "done" for r in history.revisions), history.revisions


def test_tripled_work_is_flagged_by_ks_and_unchanged_code_is_not(history: History):
    regressed = _cpu_changes(history.changes, history.regressed.title)
    flagged = [c for c in regressed if c["flagged"]]
    assert flagged, json.dumps(regressed, indent=1)
    assert all(c["effect"] > 0.5 for c in flagged)  # three times the work: far more CPU
    unchanged = _cpu_changes(history.changes, history.unchanged.title)
    assert unchanged, "the unchanged revision was compared with its baseline"
    assert not [c for c in unchanged if c["flagged"]], json.dumps(unchanged, indent=1)
    assert not _cpu_changes(history.changes, history.base.title)  # no baseline to compare with


@pytest.mark.browser
def test_trend_page_marks_the_regression_in_chromium(history: History, tmp_path: Path):
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: `python3 run.py test` installs Debian's chromium")
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_FLAGS)
        page = browser.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(f"{history.stack.url}/components/objectbuilder")
        page.wait_for_selector(".js-plotly-plot .scatterlayer .point", timeout=30_000)
        page.screenshot(path=str(tmp_path / "objectbuilder.png"), full_page=True)
        charts = page.locator(".js-plotly-plot").count()
        marked = page.evaluate(
            """() => [...document.querySelectorAll('.js-plotly-plot')].flatMap(
                   el => el.data.filter(t => (t.name || '').toLowerCase().includes('change'))
                                .flatMap(t => t.x))""")
        browser.close()
    assert not errors, errors
    assert charts >= 2
    assert history.regressed.title in marked
    assert history.unchanged.title not in marked
