"""Prometheus metrics: request counts and latency per route, jobs by state, queue depth.

Each app gets its own registry, so several apps in one process (tests) do not collide. Under
`redline server --workers N` (``PROMETHEUS_MULTIPROC_DIR`` set) every API process writes its
counts to files there and ``GET /metrics``, whichever process answers, sums them all.
"""

from __future__ import annotations

import logging
import os
import time

from fastapi import FastAPI, Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.exposition import generate_latest
from redline.server.core.config import Settings
from redline.server.db import session_factory
from redline.server.models import Job, JobState
from sqlalchemy import func, select
from starlette.types import ASGIApp, Message, Receive, Scope, Send

log = logging.getLogger(__name__)


class JobCollector:
    """Jobs by state from Postgres and the Celery queue's length from Redis, at scrape time."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings

    def collect(self):  # noqa: ANN201 - the prometheus_client collector protocol
        jobs = GaugeMetricFamily("redline_jobs", "jobs by state", labels=["state"])
        try:
            with session_factory(self.settings.database_url)() as session:
                counts = dict(
                    session.execute(select(Job.state, func.count()).group_by(Job.state)).all()
                )
            for state in JobState:
                jobs.add_metric([state.value], counts.get(state, 0))
        except Exception:  # a scrape during an outage reports what it can
            log.warning("metrics: could not count jobs", exc_info=True)
        yield jobs
        depths = self._queue_depths()
        if depths:
            family = GaugeMetricFamily(
                "redline_task_queue_depth", "tasks waiting in each Celery queue", labels=["kind"]
            )
            for kind, depth in depths.items():
                family.add_metric([kind], depth)
            yield family

    def _queue_depths(self) -> dict[str, int]:
        from redline.server.core.tasks import queue_depths

        return queue_depths(self.settings)


#: the request methods counted by name; any other is counted as "other": the HTTP server takes
#: any token as a method, and each would have made label sets of its own (a review's 200
#: requests of unknown methods, no token needed, grew /metrics from 771 bytes to 8 MB)
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})


class _Measured:
    """ASGI middleware: count and time each request by method, route template and status.

    Not ``@app.middleware("http")``: Starlette's BaseHTTPMiddleware hides a client's going
    away from ``request.is_disconnected()``, and a killed agent's long poll went on to lease a
    job to no one (`redline.server.routes.agent.lease`)."""

    def __init__(self, app: ASGIApp, requests: Counter, latency: Histogram) -> None:
        self.app, self.requests, self.latency = app, requests, latency

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start, status, counted = time.perf_counter(), 500, False  # 500 unless a response starts

        def count() -> None:  # the router names the route in the scope it was given
            nonlocal counted
            if not counted:
                counted = True
                route = getattr(scope.get("route"), "path", "unmatched")
                method = scope["method"] if scope["method"] in METHODS else "other"
                self.latency.labels(method, route).observe(time.perf_counter() - start)
                self.requests.labels(method, route, str(status)).inc()

        async def sending(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            elif message["type"] == "http.response.body" and not message.get("more_body"):
                count()  # before the last byte: a client with its answer finds it counted
            await send(message)

        try:
            await self.app(scope, receive, sending)
        finally:
            count()


def install(app: FastAPI, settings: Settings) -> None:
    """Count and time every request (by route template) and serve ``GET /metrics``."""
    registry = CollectorRegistry()
    requests = Counter(
        "redline_http_requests", "HTTP requests", ["method", "route", "status"], registry=registry
    )
    latency = Histogram(
        "redline_http_request_seconds",
        "HTTP request latency",
        ["method", "route"],
        registry=registry,
    )
    registry.register(JobCollector(settings))

    app.add_middleware(_Measured, requests=requests, latency=latency)

    @app.get("/metrics", include_in_schema=False)
    def metrics() -> Response:
        return Response(
            generate_latest(_scraped(registry, settings)), media_type=CONTENT_TYPE_LATEST
        )


def _scraped(registry: CollectorRegistry, settings: Settings) -> CollectorRegistry:
    """This process's registry, or with several API processes, all of theirs summed."""
    if not os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
        return registry
    from prometheus_client import multiprocess

    every = CollectorRegistry()
    multiprocess.MultiProcessCollector(every)
    every.register(JobCollector(settings))
    return every
