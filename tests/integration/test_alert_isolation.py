"""A receiver that hangs holds up no one (issue 14): with real `redline worker` processes as
`redline up` runs them (analysis; alerts on threads), real Postgres and Redis, and a real HTTP
receiver one of whose paths never answers within the timeout, another subscription is told,
a new revision is ingested and judged, and a later alert reaches the healthy receiver, all while
the hanging try is still in flight."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from redline.server.core.tasks import SCAN_ALERTS_TASK, TaskSender
from redline.server.db import session_factory
from redline.server.models import Component, Detection, Revision
from sqlalchemy import func, select

from tests.support import alerting
from tests.support.alerting import BASE, eager, revisions, subscribe
from tests.support.api import Api
from tests.support.history import add_execution

pytestmark = pytest.mark.slow

api, mailbox, receiver = alerting.api, alerting.mailbox, alerting.receiver  # the fixtures
REDLINE = str(Path(sys.executable).parent / "redline")
#: the workers' timeout per try: far longer than the test, so the hanging try stays in flight
TIMEOUT_S = 600


def _workers(api: Api, logs: Path) -> list[subprocess.Popen]:
    settings = api.settings
    env = {
        **os.environ,
        "REDLINE_DATABASE_URL": settings.database_url,
        "REDLINE_REDIS_URL": settings.redis_url,
        "REDLINE_QUEUE": settings.queue,
        "REDLINE_STORAGE_DIR": str(settings.storage_dir),
        "REDLINE_PUBLIC_URL": settings.public_url,
        "REDLINE_ALERT_TIMEOUT_S": str(TIMEOUT_S),
    }
    commands = {
        "analysis": ["--queues", "analysis", "--concurrency", "1"],
        "alerts": ["--queues", "alerts", "--concurrency", "2", "--no-beat"],
    }
    return [
        subprocess.Popen(
            [REDLINE, "worker", *arguments],
            env=env,
            stdout=(logs / f"{name}.log").open("ab"),
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its children go with it
        )  # fmt: skip
        for name, arguments in commands.items()
    ]


def _until(done: Callable[[], object], what: str, logs: Path, seconds: float = 120) -> None:
    """Until ``done()`` is true; a generous deadline, never a measured one."""
    deadline = time.monotonic() + seconds
    while not done():
        if time.monotonic() > deadline:
            tails = {p.name: p.read_text(errors="replace")[-2000:] for p in logs.glob("*.log")}
            pytest.fail(f"gave up waiting: {what}: {tails}")
        time.sleep(0.1)


def _states(api: Api, ident: int) -> list[tuple[str, str, int]]:
    answer = api.client.get(f"{BASE}/subscriptions/{ident}/deliveries", headers=api.tokens["admin"])
    return sorted((d["event"], d["state"], d["attempts"]) for d in answer.json())


def _judged(api: Api, title: str) -> bool:
    with session_factory(api.settings.database_url)() as session:
        revision = session.scalar(select(Revision).where(Revision.title == title))
        if revision is None or revision.analyzed_at is None:
            return False
        return bool(
            session.scalar(
                select(func.count())
                .select_from(Detection)
                .where(Detection.revision_id == revision.id)
            )
        )


def test_a_hanging_receiver_holds_up_neither_other_subscriptions_nor_ingestion_and_detection(
    api, tmp_path, receiver
):
    receiver.delays["/hang"] = TIMEOUT_S * 2  # never answers while the test runs
    hang = subscribe(api, eager(receiver, "/hang"))
    fine = subscribe(api, eager(receiver, "/fine"))
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        component = session.scalar(select(Component.id).where(Component.name == "builder"))
    logs = tmp_path / "logs"
    logs.mkdir()
    workers = _workers(api, logs)
    tasks = TaskSender(api.settings)
    try:
        ready = [logs / "analysis.log", logs / "alerts.log"]
        _until(lambda: all(" ready." in p.read_text() for p in ready), "both workers start", logs)
        assert tasks.send(SCAN_ALERTS_TASK, component)
        # both told at once: the one hangs, the other is delivered and stored as such
        _until(lambda: receiver.to("/hang"), "the hanging receiver is called", logs)
        _until(
            lambda: _states(api, fine["id"]) == [("regression", "delivered", 1)],
            "the other subscription is told",
            logs,
        )
        # a new revision is ingested and judged by the analysis worker meanwhile
        with session_factory(database_url)() as session:
            rng = np.random.default_rng(7)
            later = add_execution(
                session, tmp_path, "builder", "r7", "0007", {"cpu": rng.normal(14.0, 0.7, 60)}
            )
        assert tasks.ingest(later.id)
        _until(lambda: _judged(api, "r7"), "r7 is ingested and judged", logs)
        # and an alert raised after the hang began reaches the healthy receiver
        fault = {"target": "cpu_percent", "started": True, "residual": 61.5, "threshold": 4.0,
                 "step": 60, "host": "robot-1", "process": "builder"}  # fmt: skip
        assert api.post(f"{BASE}/runtime-alerts", "agent", fault).status_code == 201
        _until(
            lambda: ("runtime_fault", "delivered", 1) in _states(api, fine["id"]),
            "the later alert reaches the other subscription",
            logs,
        )
        # all of that while the first try to the hanging receiver was still waiting
        assert ("regression", "sending", 1) in _states(api, hang["id"])
    finally:
        for worker in workers:  # at once: a warm shutdown would wait for the hanging try
            os.killpg(worker.pid, signal.SIGKILL)
            worker.wait(timeout=30)
