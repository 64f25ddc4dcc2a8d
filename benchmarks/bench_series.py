"""A series of 1,000 revisions served over HTTP: p95 against the 50 ms target, same run.

A `redline server` process on real Postgres holding 1,000 revisions of one component, each with
one execution summarizing 50 series (50,000 summary rows). `GET /api/v1/series/{id}` is asked
for one series' 1,000 points, 200 times (series chosen round-robin), with `/healthz` timed
alongside as the server's floor.

Run: .venv/bin/python benchmarks/bench_series.py   (prints figures; not a test)
"""

from __future__ import annotations

import statistics
import time

import httpx
from _service import api_server, database
from redline.server.db import session_factory
from redline.server.models import Component, Execution, Job, JobState, Revision, Series, Summary
from redline.server.services.revisions import order_key
from sqlalchemy import insert, select

REVISIONS, SERIES, REQUESTS, TARGET_MS = 1000, 50, 200, 50.0
STATS = dict(
    n=100, mean=1.0, std=0.1, min=0.8, p5=0.85, p25=0.95, p50=1.0, p75=1.05, p95=1.15, max=1.3
)


def _history(url: str) -> list[int]:
    """Bulk-insert the history; returns the series ids."""
    with session_factory(url)() as session:
        component = Component(name="bench", repo="/bench.git", suite="s.toml")
        session.add(component)
        session.flush()
        series = [
            Series(
                component_id=component.id,
                case="c",
                phase="p",
                params="{}",
                process="proc",
                counter=f"counter{n}",
            )
            for n in range(SERIES)
        ]
        session.add_all(series)
        session.execute(
            insert(Revision),
            [
                dict(
                    component_id=component.id,
                    title=f"r{n}",
                    sort_key=str(n),
                    order_key=order_key(str(n)),
                )
                for n in range(REVISIONS)
            ],
        )
        revisions = list(session.scalars(select(Revision.id).order_by(Revision.id)))
        session.execute(
            insert(Job),
            [dict(revision_id=r, execution_index=0, state=JobState.done) for r in revisions],
        )
        jobs = list(session.scalars(select(Job.id).order_by(Job.id)))
        session.execute(
            insert(Execution),
            [
                dict(job_id=j, revision_id=r, recording_path="", sha256=f"{j:064d}")
                for j, r in zip(jobs, revisions, strict=True)
            ],
        )
        executions = list(session.scalars(select(Execution.id).order_by(Execution.id)))
        session.execute(
            insert(Summary),
            [dict(execution_id=e, series_id=s.id, **STATS) for e in executions for s in series],
        )
        session.commit()
        return [s.id for s in series]


def _p95(samples: list[float]) -> float:
    return statistics.quantiles(samples, n=20)[-1]


def main() -> None:
    with database() as url, api_server(url) as (server, _tokens):
        ids = _history(url)
        with httpx.Client(base_url=server) as client:
            points = len(client.get(f"/api/v1/series/{ids[0]}").json()["summaries"])
            assert points == REVISIONS, points
            series, floor = [], []
            for n in range(REQUESTS):
                start = time.perf_counter()
                client.get(f"/api/v1/series/{ids[n % SERIES]}").raise_for_status()
                series.append((time.perf_counter() - start) * 1e3)
                start = time.perf_counter()
                client.get("/healthz").raise_for_status()
                floor.append((time.perf_counter() - start) * 1e3)
        p95 = _p95(series)
        print(
            f"series of {points} revisions: median {statistics.median(series):.1f} ms, "
            f"p95 {p95:.1f} ms; /healthz p95 {_p95(floor):.1f} ms"
        )
        print(
            f"p95 / target ({TARGET_MS:.0f} ms): {p95 / TARGET_MS:.2f}x; "
            f"p95 / healthz p95: {p95 / _p95(floor):.1f}x"
        )


if __name__ == "__main__":
    main()
