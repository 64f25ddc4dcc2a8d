"""What the alert tests share: a real SMTP server and HTTP receiver as fixtures, an app whose
settings send to them (a 1 s timeout, 10 ms retries, 5 tries), and helpers that subscribe, judge
revisions and run the outbox as a worker does.

Import the fixtures into a test module (``from tests.support.alerting import api, ...``)."""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from redline.server.core.config import Settings
from redline.server.db import session_factory
from redline.server.models import Alert, Component, Delivery, DetectionConfigRow
from redline.worker.deliver import claim, deliver_due
from redline.worker.detection import detect_revision
from redline.worker.follow_ups import tell_component
from redline.worker.ingest import ingest_execution
from redline.worker.reanalysis import reanalyze_component
from sqlalchemy import select, update

from tests.support.api import Api, api_with
from tests.support.history import add_execution
from tests.support.receivers import Mailbox, Receiver, http_receiver, smtp_server

BASE = "/api/v1/components/builder"


@pytest.fixture
def mailbox(tmp_path: Path):
    with smtp_server(tmp_path) as box:
        yield box


@pytest.fixture
def receiver():
    with http_receiver() as found:
        yield found


@pytest.fixture
def api(services, tmp_path: Path, mailbox: Mailbox):
    with api_with(
        services,
        tmp_path,
        public_url="https://redline.example",
        smtp_host=mailbox.host,
        smtp_port=mailbox.port,
        smtp_user=mailbox.user,
        smtp_password=mailbox.password,
        smtp_tls="starttls",
        smtp_ca_file=mailbox.ca_file,
        alert_timeout_s=1.0,
        alert_retry_s=0.01,
        alert_max_attempts=5,
    ) as driver:
        driver.component()
        with session_factory(driver.settings.database_url)() as session:
            component = session.scalar(select(Component).where(Component.name == "builder"))
            session.add(DetectionConfigRow(component_id=component.id, config={"methods": ["ks"]}))
            session.commit()
        yield driver


def subscribe(api: Api, body: dict, component: str | None = "builder") -> dict:
    path = f"/api/v1/components/{component}/subscriptions" if component else "/api/v1/subscriptions"
    answer = api.post(path, "admin", body)
    assert answer.status_code == 201, answer.text
    return answer.json()


def eager(receiver: Receiver, path: str) -> dict:
    """A webhook subscription told of regressions as soon as they are flagged."""
    return {"kind": "webhook", "url": receiver.url + path, "confirmed_only": False}


def judged(api: Api, tmp_path: Path, runs: list[dict[str, np.ndarray]], first: int = 1) -> None:
    """Revisions r{first}.. of 'builder' with these counters' samples, ingested and judged."""
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        executions = [
            add_execution(session, tmp_path, "builder", f"r{n}", f"{n:04d}", counters)
            for n, counters in enumerate(runs, start=first)
        ]
    for execution in executions:
        ingest_execution(database_url, execution.id)
        detect_revision(database_url, execution.revision_id)


def revisions(api: Api, tmp_path: Path, cpus: list[float], first: int = 1, seed: int = 5) -> None:
    """Revisions r{first}.. of 'builder' with cpu series of these means, ingested and judged."""
    rng = np.random.default_rng(seed + first)
    judged(api, tmp_path, [{"cpu": rng.normal(cpu, cpu / 20, 60)} for cpu in cpus], first)


def cpu_and_rss(api: Api, tmp_path: Path) -> None:
    """Revisions r1..r6 of 'builder' judged with a floor of 5 %: cpu +40 % at r6 is flagged,
    rss +3 % is not (`grow_by_rss` flags it)."""
    floor = {"methods": ["ks"], "thresholds": {"ks": {"min_effect": 0.05}}}
    with session_factory(api.settings.database_url)() as session:
        session.execute(update(DetectionConfigRow).values(config=floor))
        session.commit()
    rng = np.random.default_rng(3)
    means = [(10.0, 100.0)] * 5 + [(14.0, 103.0)]
    runs = [{"cpu": rng.normal(c, 0.2, 60), "rss": rng.normal(r, 0.05, 60)} for c, r in means]
    judged(api, tmp_path, runs)


def grow_by_rss(api: Api) -> None:
    """After `cpu_and_rss`: the floor lowered to 1 % and the history analysed again, so the
    regression at r6 grows by rss's +3 %."""
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        lower = {"methods": ["ks"], "thresholds": {"ks": {"min_effect": 0.01}}}
        session.execute(update(DetectionConfigRow).values(config=lower))
        session.commit()
    reanalyze_component(database_url, 1)


def a_period_later(api: Api) -> None:
    """As if every alert so far was made two days ago: a regression's growth may be told."""
    with session_factory(api.settings.database_url)() as session:
        session.execute(update(Alert).values(created=Alert.created - timedelta(days=2)))
        session.commit()


def _deliver(database_url: str, settings: Settings) -> None:
    deliver_due(database_url, settings)


def killed_mid_send(api: Api, arrived: Callable[[], object]) -> None:
    """Run the outbox in a process of its own (a 60 s timeout) until ``arrived()`` says the
    receiver has the message, kill that process mid-send, check the delivery stays leased,
    then let its lease lapse."""
    slow = api.settings.model_copy(update={"alert_timeout_s": 60.0})
    worker = multiprocessing.get_context("spawn").Process(
        target=_deliver, args=(api.settings.database_url, slow)
    )
    worker.start()
    deadline = time.monotonic() + 60
    while not arrived() and time.monotonic() < deadline:
        time.sleep(0.05)
    worker.kill()
    worker.join()
    assert claim(api.settings.database_url, 10, lease=timedelta(days=1)) == []  # leased
    with session_factory(api.settings.database_url)() as session:  # its lease lapses
        session.execute(update(Delivery).values(lease_until=Delivery.created))
        session.commit()


def scan(api: Api) -> None:
    """What the worker does after a detection, short of sending: the alerts and deliveries."""
    with session_factory(api.settings.database_url)() as session:
        component = session.scalar(select(Component.id).where(Component.name == "builder"))
        tell_component(session, component)
        session.commit()


def alert(api: Api, rounds: int = 20) -> None:
    """What the worker does after a detection: scan, then send until nothing is due."""
    scan(api)
    for _ in range(rounds):
        done = deliver_due(api.settings.database_url, api.settings)
        if done["next"] is None:
            return
        time.sleep(0.05)


def deliveries(api: Api, ident: int | None = None) -> list[dict]:
    path = f"{BASE}/subscriptions/{ident}/deliveries" if ident else f"{BASE}/deliveries"
    answer = api.client.get(path, headers=api.tokens["admin"])
    assert answer.status_code == 200, answer.text
    return answer.json()
