"""The component page's cost against the length of the history (issue 13's goal: ≤ 200 ms at p95
for 1,000 revisions × 50 series, and flat from 100 to 10,000 revisions).

    .venv/bin/python benchmarks/bench_dashboard.py [--revisions 100 1000 10000] [--requests 40]
        [--counters 10] [--sets 5]

For each history length R it fills a fresh database with one component of R revisions, each
with one execution and 50 series (5 parameter sets × 10 counters, or ``--sets`` × ``--counters``:
a trial's import of 20,000 series is ``--counters 4000``; the summaries an import or an agent's
upload stores, one detection per series, a flagged change in a regression every 50
revisions), bulk-inserted in SQL so that 10,000 revisions take seconds rather than the hour the
HTTP import would, then analysed (``ANALYZE``: the statistics autovacuum would have gathered).
A real `redline server` (child process) then answers:

- the first request of the component page (a cache miss: the page renders its charts), then
  ``--requests`` more (served from the cache, as after the worker has rendered them): p50, p95
  (nearest rank: the ceil(0.95 n)-th fastest);
- the reference in the same run: ``/healthz`` (which asks the database), and the page's ratio
  to it;
- with Debian's Chromium (when installed), the time from navigation to the first chart drawn.

One JSON line per R: ``{"revisions": R, "series": S, "p50_ms", "p95_ms", "miss_ms", ...}``.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
import uuid
from pathlib import Path

import httpx
import numpy as np
from _service import api_server, database
from redline.server.db import bulk_insert, session_factory
from redline.server.models import (
    Component,
    Detection,
    Execution,
    Job,
    JobState,
    Regression,
    Revision,
    Series,
    Summary,
    utcnow,
)
from redline.server.services.revisions import order_key
from sqlalchemy import text

COMPONENT = "bench"
PARAMS = [{"legs": legs} for legs in (1, 2, 4, 8, 16)]
COUNTERS = ["cpu_percent", "rss_bytes", "uss_bytes", "pss_bytes", "threads", "io_read_bytes",
            "io_write_bytes", "ctx_switches", "fds", "cpu_user_percent"]  # fmt: skip
FLAG_EVERY = 50
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]


def counters(count: int) -> list[str]:
    """The first ``count`` of `COUNTERS`, then made-up names: a wide import's."""
    return COUNTERS[:count] + [f"counter_{n:05d}" for n in range(len(COUNTERS), count)]


def fill(url: str, revisions: int, names: list[str], sets: list[dict[str, int]]) -> None:
    """One component, ``revisions`` revisions of one execution and a series per counter of
    ``names`` and parameter set of ``sets`` each."""
    rng = np.random.default_rng(13)
    session = session_factory(url)()
    now = utcnow()
    component = Component(name=COMPONENT, repo="https://git.example/bench.git", suite="perf.toml")
    session.add(component)
    session.flush()
    series = [
        Series(
            component_id=component.id,
            case="track",
            phase="steady",
            params=json.dumps(params, sort_keys=True),
            process="bench",
            counter=counter,
        )
        for params in sets
        for counter in names
    ]
    session.add_all(series)
    session.flush()
    chunk = 500
    for first in range(0, revisions, chunk):
        count = min(chunk, revisions - first)
        rows = [
            Revision(
                component_id=component.id,
                title=f"r{n:05d}",
                sort_key=str(n),
                order_key=order_key(str(n)),
                commit=uuid.uuid4().hex,
                committed_at=now,
                analyzed_at=now,
            )
            for n in range(first, first + count)
        ]
        session.add_all(rows)
        session.flush()
        jobs = [Job(revision_id=r.id, execution_index=0, state=JobState.done) for r in rows]
        session.add_all(jobs)
        session.flush()
        executions = [
            Execution(
                job_id=job.id,
                revision_id=job.revision_id,
                recording_path="",
                sha256=uuid.uuid4().hex,
            )
            for job in jobs
        ]
        session.add_all(executions)
        session.flush()
        summaries, detections = [], []
        for number, (revision, execution) in enumerate(zip(rows, executions, strict=True)):
            flagged = (number + 1) % FLAG_EVERY == 0  # its first series' verdict is a change
            for at, one in enumerate(series):
                mean = 10.0 + at + float(rng.normal(0, 0.5))
                quantiles = np.sort(rng.normal(mean, 1.0, 9))
                summaries.append(
                    dict(
                        execution_id=execution.id,
                        series_id=one.id,
                        n=20,
                        mean=mean,
                        std=1.0,
                        min=float(quantiles[0]),
                        p5=float(quantiles[1]),
                        p25=float(quantiles[2]),
                        p50=float(quantiles[4]),
                        p75=float(quantiles[6]),
                        p95=float(quantiles[7]),
                        max=float(quantiles[8]),
                    )
                )
                if flagged and at == 0:
                    continue
                detections.append(
                    dict(
                        series_id=one.id,
                        revision_id=revision.id,
                        baseline_revisions=6,
                        method="execution_shift",
                        verdict="no change",
                        reason="",
                        score=0.1,
                        effect=0.01,
                        direction="none",
                        flagged=False,
                        confirmation="",
                        confirmation_reason="",
                        created=now,
                    )
                )
        bulk_insert(session, Summary.__table__, summaries)
        bulk_insert(session, Detection.__table__, detections)
        for revision in rows[FLAG_EVERY - 1 :: FLAG_EVERY]:
            regression = Regression(
                component_id=component.id,
                good_revision_id=revision.id,
                bad_revision_id=revision.id,
                good_key=revision.order_key,
                bad_key=revision.order_key,
                confirmation="confirmed",
            )
            session.add(regression)
            session.flush()
            session.add(
                Detection(
                    series_id=series[0].id,
                    revision_id=revision.id,
                    method="execution_shift",
                    verdict="change",
                    score=3.0,
                    effect=0.12,
                    direction="increase",
                    flagged=True,
                    confirmation="held",
                    regression_id=regression.id,
                )
            )
        session.commit()
    # what autovacuum does within a minute of such a load: without statistics the planner takes
    # 0.5 % of the revisions for the component's and sorts them all for the newest (a live
    # server's tables have theirs; measured without, 10,000 revisions read 75 ms at p50)
    session.execute(text("ANALYZE"))
    session.commit()
    session.close()


def timed(client: httpx.Client, path: str) -> tuple[float, int]:
    began = time.perf_counter()
    answer = client.get(path)
    elapsed = (time.perf_counter() - began) * 1000
    answer.raise_for_status()
    return elapsed, len(answer.content)


def first_chart_ms(url: str) -> float | None:
    """Navigation to the first trend chart drawn, in Debian's Chromium; None without it."""
    if not CHROMIUM.exists():
        return None
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_FLAGS)
        page = browser.new_page()
        page.goto(f"{url}/")  # a warm browser: plotly.js from its cache on the timed visit
        page.goto(f"{url}/components/{COMPONENT}")
        page.wait_for_selector(
            ".js-plotly-plot .scatterlayer .trace", timeout=60_000, state="attached"
        )
        began = time.perf_counter()
        page.goto(f"{url}/components/{COMPONENT}")
        page.wait_for_selector(
            ".js-plotly-plot .scatterlayer .trace", timeout=60_000, state="attached"
        )
        elapsed = (time.perf_counter() - began) * 1000
        browser.close()
    return elapsed


def measure(revisions: int, requests: int, names: list[str], sets: list[dict[str, int]]) -> dict:
    with database() as url:
        began = time.monotonic()
        fill(url, revisions, names, sets)
        filled = time.monotonic() - began
        with (
            api_server(url) as (server, _tokens),
            httpx.Client(base_url=server, timeout=120) as client,
        ):
            miss, _ = timed(client, f"/components/{COMPONENT}")
            page = [timed(client, f"/components/{COMPONENT}") for _ in range(requests)]
            reference = [timed(client, "/healthz")[0] for _ in range(requests)]
            chart = first_chart_ms(server)
    times = sorted(ms for ms, _ in page)
    p50 = statistics.median(times)
    reference_p50 = statistics.median(reference)
    return {
        "revisions": revisions,
        "series": len(sets) * len(names),
        "p50_ms": round(p50, 1),
        "p95_ms": round(times[max(0, math.ceil(0.95 * len(times)) - 1)], 1),  # nearest rank
        "miss_ms": round(miss, 1),
        "page_kib": round(page[0][1] / 1024),
        "healthz_p50_ms": round(reference_p50, 1),
        "ratio_to_healthz": round(p50 / reference_p50, 1),
        "first_chart_ms": None if chart is None else round(chart),
        "fill_s": round(filled, 1),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--revisions", type=int, nargs="+", default=[100, 1000, 10000])
    parser.add_argument("--requests", type=int, default=40)
    parser.add_argument("--counters", type=int, default=len(COUNTERS), help="counters a set")
    parser.add_argument("--sets", type=int, default=len(PARAMS), help="parameter sets")
    args = parser.parse_args()
    sets = PARAMS[: args.sets] + [{"legs": 2**n} for n in range(len(PARAMS), args.sets)]
    for revisions in args.revisions:
        row = measure(revisions, args.requests, counters(args.counters), sets)
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
