"""A component's history for the page tests: revisions of 'builder' measured at two parameter
sets, ingested and judged; what the tests read back from a page; and Debian's Chromium driven by
Playwright, with a page that collects console errors and requests to other hosts."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import urlparse

import numpy as np
from redline.recording import RecordingWriter
from redline.server.db import session_factory
from redline.server.models import DetectionConfigRow
from redline.server.schemas.components import ComponentCreate
from redline.server.services.components import create_component

from tests.support.history import add_executions, ingest_and_detect


def two_parameter_sets(
    path: Path, run: dict[str, str], counters: dict[str, np.ndarray], case: str = "build"
) -> Path:
    """A recording of ``case`` at legs 2 and 8 (twice the counters' values at 8), with the
    component's output (markup in it, to be shown as text)."""
    with RecordingWriter(path) as writer:
        writer.metadata("redline.run", run)
        t_ns = 1_000_000_000
        for legs in (2, 8):
            params = {"legs": legs}
            writer.marker("begin", case, "steady", params, warmup=False, t_ns=t_ns)
            for index in range(len(counters["cpu"])):
                t_ns += 10_000_000
                sample = {
                    name: float(values[index]) * legs / 2 for name, values in counters.items()
                }
                writer.counters("builder", 4242, sample, t_ns)
            t_ns += 10_000_000
            writer.marker("end", case, "steady", params, warmup=False, t_ns=t_ns)
        writer.log("builder", b"builder ready\n<script>alert('from the log')</script>\n")
    return path


def history(
    database_url: str, tmp_path: Path, cpus: list[float], start: int = 1, case: str = "build"
) -> None:
    """Revisions r<start>.. of 'builder' with cpu and rss at legs 2 and 8, ingested and judged
    (by KS alone: one execution each)."""
    rng = np.random.default_rng(start)
    with session_factory(database_url)() as session:
        if start == 1:
            component = create_component(session, ComponentCreate(name="builder"))
            session.add(DetectionConfigRow(component_id=component.id, config={"methods": ["ks"]}))
            session.commit()
        executions = []
        for number, cpu in enumerate(cpus, start=start):
            counters = {"cpu": rng.normal(cpu, cpu / 20, 60), "rss": rng.normal(1e6, 1e3, 60)}
            executions += add_executions(
                session,
                tmp_path,
                "builder",
                f"r{number}",
                str(number),
                [counters],
                record=two_parameter_sets,
                case=case,
            )
    ingest_and_detect(database_url, executions)


def emptied(services, database_url: str, folder: Path):  # noqa: ANN001, ANN201
    """Settings of a server over ``database_url``, emptied (tokens made afresh), storing in
    ``folder``, on a queue of its own."""
    import uuid

    from redline.server.core.config import Settings

    from tests.support.api import emptied_with_tokens

    emptied_with_tokens(database_url)
    return Settings(
        database_url=database_url,
        redis_url=services.redis_url,
        storage_dir=folder / "storage",
        queue=f"test-{uuid.uuid4().hex[:8]}",
    )


@contextmanager
def page_client(services, database_url: str, tmp_path: Path) -> Iterator[object]:  # noqa: ANN001
    """The real app over an emptied database, as a TestClient."""
    from fastapi.testclient import TestClient
    from redline.server.app import create_app

    with TestClient(create_app(emptied(services, database_url, tmp_path))) as client:
        yield client


def trend_data(page: str) -> dict:
    match = re.search(r'<script type="application/json" id="trend-data">(.*?)</script>', page, re.S)
    assert match, "the page carries its trend data"
    return json.loads(match.group(1))


def form_token(page: str) -> str:
    match = re.search(r'name="csrf" value="([^"]+)"', page)
    assert match, "a signed-in page carries its form token"
    return match.group(1)


def sign_in(client, data: dict[str, str], **options):  # noqa: ANN001, ANN201 - a TestClient
    """Post the sign-in form as a browser does: its page first, for the form's token (and the
    cookie it goes with), then the form with ``data``."""
    page = client.get("/signin").text
    match = re.search(r'action="/signin".*?name="csrf" value="([^"]+)"', page, re.S)
    assert match, "the sign-in form carries its token"
    return client.post("/signin", data={**data, "csrf": match.group(1)}, **options)


CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]


@contextmanager
def chromium() -> Iterator[object]:
    """Debian's Chromium under Playwright (never a downloaded browser)."""
    import pytest
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: `python3 run.py test` installs Debian's chromium")
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_FLAGS)
        try:
            yield browser
        finally:
            browser.close()


class Watched:
    """A page whose console errors, page errors and requests to other hosts are collected; with
    ``REDLINE_SCREENSHOTS=DIR``, `visit` saves a screenshot of each page it loads there."""

    def __init__(self, browser, base: str) -> None:  # noqa: ANN001 - a Playwright Browser
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

    def visit(self, url: str, name: str | None = None) -> None:
        """Load ``url`` (200 expected); ``name``: the screenshot's, if one is wanted."""
        answer = self.page.goto(url)
        assert answer is not None and answer.status == 200, f"{url}: {answer and answer.status}"
        self.page.wait_for_load_state("networkidle")
        if name:
            self.shot(name)

    def shot(self, name: str) -> None:
        """With ``REDLINE_SCREENSHOTS=DIR``, a screenshot of the page as it is, as DIR/name.png."""
        folder = os.environ.get("REDLINE_SCREENSHOTS")
        if folder:
            Path(folder).mkdir(parents=True, exist_ok=True)
            self.page.screenshot(path=str(Path(folder) / f"{name}.png"), full_page=True)

    def sign_in(self, base: str, name: str, password: str) -> None:
        """Sign in through the sign-in form, as a person does."""
        self.visit(f"{base}/signin")
        self.page.fill("input[name=name]", name)
        self.page.fill("input[name=password]", password)
        self.page.click("form.signin button[type=submit]")
        self.page.wait_for_load_state("networkidle")

    def first_chart_traces(self) -> int:
        """How many traces the page's first chart has, once one is drawn."""
        self.page.wait_for_selector(
            ".js-plotly-plot .scatterlayer .trace, .barlayer", state="attached"
        )
        first = "() => document.querySelector('.js-plotly-plot').data.length"
        return int(self.page.evaluate(first))
