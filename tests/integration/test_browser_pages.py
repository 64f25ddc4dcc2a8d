"""Every page in Debian's Chromium (Playwright), against a real server on real Postgres holding a
judged history: no console error and no request to another host on any page, charts with their
traces, filters that change the address and the charts, triage done in the page and stored, and
every control of a page reachable with the keyboard.

With ``REDLINE_SCREENSHOTS=DIR`` it saves a screenshot of each page there (docs/ui.md shows
them: ``REDLINE_SCREENSHOTS=docs/ui python3 run.py test tests/integration/test_browser_pages.py``).
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlparse

import pytest
from redline.server.core.config import Settings
from redline.server.db import migrate, session_factory
from redline.server.services.signin import create_user

from tests.support.api import emptied_with_tokens
from tests.support.pages import history
from tests.support.servers import Services, fresh_database, live_server

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]
PASSWORD = "correct horse battery"


@pytest.fixture(scope="module")
def site(services: Services, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, str]]:
    """A running server over a judged history of 'builder' (a tenfold CPU change at r4): its
    address and the database's."""
    database_url, _ = fresh_database(services.database_url)
    migrate(database_url)
    tmp = tmp_path_factory.mktemp("browser")
    settings = Settings(
        database_url=database_url,
        redis_url=services.redis_url,
        storage_dir=tmp / "storage",
        queue=f"test-{uuid.uuid4().hex[:8]}",
    )
    emptied_with_tokens(database_url)
    history(database_url, tmp, [20.0, 20.0, 20.0, 200.0, 200.0, 200.0])
    with session_factory(database_url)() as session:
        create_user(session, "ada", PASSWORD, "admin")
    with live_server(settings) as url:
        yield url, database_url


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: `python3 run.py test` installs Debian's chromium")
    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_FLAGS)
        yield chromium
        chromium.close()


class Watched:
    """A page whose console errors, page errors and requests to other hosts are collected."""

    def __init__(self, browser, base: str) -> None:
        self.page = browser.new_page()
        self.errors: list[str] = []
        self.foreign: list[str] = []
        self.page.on("pageerror", lambda exc: self.errors.append(str(exc)))
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        host = urlparse(base).netloc
        self.page.on(
            "request",
            lambda r: (
                self.foreign.append(r.url) if urlparse(r.url).netloc not in (host, "") else None
            ),
        )

    def visit(self, url: str, name: str) -> None:
        answer = self.page.goto(url)
        assert answer is not None and answer.status == 200, f"{url}: {answer and answer.status}"
        self.page.wait_for_load_state("networkidle")
        folder = os.environ.get("REDLINE_SCREENSHOTS")
        if folder:
            Path(folder).mkdir(parents=True, exist_ok=True)
            self.page.screenshot(path=str(Path(folder) / f"{name}.png"), full_page=True)


def _ids(site: tuple[str, str]) -> tuple[int, int, int]:
    """A regression's, one of its detections' and an execution's ids."""
    import httpx

    base = f"{site[0]}/api/v1/components/builder"
    regression = httpx.get(f"{base}/regressions").json()[0]
    detail = httpx.get(f"{base}/regressions/{regression['id']}").json()
    revision = httpx.get(f"{base}/revisions/r4").json()
    return regression["id"], detail["flagged"][0]["id"], revision["jobs"][0]["execution"]["id"]


def test_every_page_loads_clean_with_its_charts(site, browser):
    base = site[0]
    regression, detection, execution = _ids(site)
    watched = Watched(browser, base)
    pages = {
        "home": "/",
        "component": "/components/builder",
        "revision": "/components/builder/revisions/r4",
        "compare": "/components/builder/compare?base=r3&candidate=r4",
        "regressions": "/regressions",
        "regression": f"/regressions/{regression}",
        "why-flagged": f"/detections/{detection}",
        "execution": f"/executions/{execution}",
        "signin": "/signin",
    }
    for name, path in pages.items():
        watched.visit(base + path, name)
        if name in ("component", "compare", "why-flagged", "execution"):
            watched.page.wait_for_selector(
                ".js-plotly-plot .scatterlayer .trace, .barlayer", state="attached"
            )
            traces = watched.page.evaluate(
                "() => document.querySelector('.js-plotly-plot').data.length"
            )
            assert traces > 0, name
    assert not watched.errors, watched.errors
    assert not watched.foreign, watched.foreign


def test_filters_change_the_address_and_the_charts(site, browser):
    base = site[0]
    watched = Watched(browser, base)
    watched.visit(f"{base}/components/builder", "component")
    before = watched.page.locator("#charts .chart").count()
    watched.page.select_option("select[name=counter]", "cpu")
    watched.page.check("input[name=median]")
    watched.page.click("#filters button[type=submit]")
    watched.page.wait_for_load_state("networkidle")
    assert "counter=cpu" in watched.page.url and "median=1" in watched.page.url
    after = watched.page.locator("#charts .chart").count()
    assert 0 < after < before
    watched.page.wait_for_selector(".js-plotly-plot .scatterlayer .trace", state="attached")
    names = watched.page.evaluate(
        "() => document.querySelector('.js-plotly-plot').data.map(t => t.name || '')"
    )
    assert any("moving median" in name for name in names), names
    assert not watched.errors, watched.errors


def test_triage_in_the_page_is_stored_and_needs_a_sign_in(site, browser):
    import httpx

    base = site[0]
    regression, _, _ = _ids(site)
    watched = Watched(browser, base)
    watched.visit(f"{base}/regressions/{regression}", "regression-signed-out")
    assert watched.page.locator("#triage").count() == 0
    watched.page.click("text=Sign in")
    watched.page.fill("input[name=name]", "ada")
    watched.page.fill("input[name=password]", PASSWORD)
    watched.page.click("form.signin button[type=submit]")
    watched.page.wait_for_url(f"**/regressions/{regression}")
    watched.page.check("input[name=state][value=acknowledged]")
    watched.page.fill("input[name=comment]", "looking at it")
    watched.page.click("#triage button[type=submit]")
    watched.page.wait_for_load_state("networkidle")
    stored = httpx.get(f"{base}/api/v1/components/builder/regressions/{regression}").json()
    assert stored["state"] == "acknowledged"
    assert stored["history"][-1]["who"] == "ada"
    assert "looking at it" in watched.page.content()
    assert not watched.errors, watched.errors


def test_keyboard_reaches_every_control(site, browser):
    base = site[0]
    regression, _, _ = _ids(site)
    watched = Watched(browser, base)
    for path in ("/components/builder", f"/regressions/{regression}", "/signin"):
        watched.visit(base + path, "keyboard")
        # a group of radio buttons is one stop of the Tab key (arrows move within it)
        controls = watched.page.evaluate(
            """() => { const groups = new Set();
                 return [...document.querySelectorAll(
                   'a[href], button, select, input:not([type=hidden]), textarea')]
                 .filter(el => el.offsetParent !== null && !el.disabled)
                 .filter(el => el.type !== 'radio' || !groups.has(el.name) && groups.add(el.name))
                 .map((el, i) => { el.dataset.control = i; return i; }); }"""
        )
        # Charts drawn after the count add their own stops (plotly's toolbar), so Tab on
        # until every counted control has had the focus, within a generous bound.
        reached: set[int] = set()
        for _ in range(4 * len(controls) + 50):
            watched.page.keyboard.press("Tab")
            found = watched.page.evaluate("() => document.activeElement.dataset.control")
            if found is not None:
                reached.add(int(found))
            if reached >= set(controls):
                break
        missed = sorted(set(controls) - reached)
        assert not missed, f"{path}: controls {missed} of {len(controls)} never got the focus"
