"""Alerts under load and outage (issue 14): 1,000 regressions across 100 subscriptions, half of the
receivers failing at first. Goal: every delivery done exactly once after recovery; the delay from
detection to delivery at p50 and p95.

    .venv/bin/python benchmarks/bench_alerts.py [--regressions 1000] [--components 100]
        [--subscriptions 100] [--outage 20] [--rate 10] [--json]

What runs is the real path after detection: Postgres (``REDLINE_DATABASE_URL`` or an embedded
one), Redis (``REDLINE_REDIS_URL`` or an embedded one), two real `redline worker` processes as
`redline up` runs them (analysis with the beat schedule; alerts on threads), and a real HTTP
receiver. The regressions are written as detection stores them (a component's revisions, series,
flagged detections grouped into confirmed regressions), ``--rate`` per second, each followed by
the `redline.scan_alerts` task detection queues; the detectors themselves are not run (their
speed is bench_detect's). ``--components`` components each have ``subscriptions / components``
webhook subscriptions, so each regression is told to that many receivers (by default one: 1,000
deliveries; ``--components 10`` makes it ten, 10,000 deliveries); half of the receivers
answer 500 for the first ``--outage`` seconds. Retries use the defaults (30 s, doubling, jitter).

Measured: per delivery, the delay from its regression's detection (the rows' commit) to the
receiver's first 2xx answer; p50/p95 for the healthy half and for the failing-at-first half; how
many delivery ids were answered 2xx more than once (goal 0) and how many were never (goal 0).
The reference in the same run: one HTTP POST to the same receiver with the client deliveries use
(the floor of a delivery).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections import defaultdict
from contextlib import ExitStack
from datetime import UTC, datetime
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from _service import database
from redline.commands.stack import redline_executable
from redline.server.core.config import Settings
from redline.server.core.tasks import SCAN_ALERTS_TASK, celery_client
from redline.server.db import session_factory
from redline.server.models import (
    Component,
    Delivery,
    Detection,
    DetectionConfigRow,
    Regression,
    RegressionState,
    Revision,
    Series,
    Subscription,
)
from redline.server.services.revisions import order_key
from redline.worker.sending import http_client
from sqlalchemy import func, select


class Receivers:
    """One HTTP server; path /r{i} is receiver i. Failing ones answer 500 until ``until``."""

    def __init__(self, failing: set[int]) -> None:
        self.failing, self.until = failing, 0.0
        self.lock = threading.Lock()
        self.ok: dict[str, list[float]] = defaultdict(list)  # delivery id -> 2xx answer times
        self.tries = 0
        receivers = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 (http.server's name)
                self.rfile.read(int(self.headers.get("Content-Length") or 0))
                index = int(self.path.lstrip("/r") or -1)
                down = index in receivers.failing and time.time() < receivers.until
                with receivers.lock:
                    receivers.tries += 1
                    if not down and self.headers.get("X-Redline-Delivery"):
                        receivers.ok[self.headers["X-Redline-Delivery"]].append(time.time())
                self.send_response(500 if down else 200)
                self.end_headers()

            def log_message(self, *args: object) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()


def redis_url(stack: ExitStack) -> str:
    configured = os.environ.get("REDLINE_REDIS_URL")
    if configured:
        return configured
    from redline.commands.embedded import EmbeddedServices, start_redis

    folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="redline-bench-redis-")))
    url, handle = start_redis(folder / "redis")
    stack.callback(EmbeddedServices(redis=handle).stop)
    return url


def setup(url: str, args: argparse.Namespace, receivers: Receivers) -> list[int]:
    """Components with their baseline revision, and the subscriptions; returns component ids."""
    per = args.subscriptions // args.components
    ids = []
    with session_factory(url)() as session:
        for c in range(args.components):
            component = Component(name=f"bench{c}")
            session.add(component)
            session.flush()
            session.add(DetectionConfigRow(component_id=component.id, config={"methods": ["ks"]}))
            for s in range(per):
                index = c * per + s
                session.add(
                    Subscription(
                        component_id=component.id,
                        kind="webhook",
                        url=f"{receivers.url}/r{index}",
                        secret="bench",
                    )
                )
            ids.append(component.id)
        session.commit()
    return ids


def detect(url: str, component_id: int, number: int) -> datetime:
    """A regression as detection stores it: revisions r{2n-1} (good) and r{2n} (bad), a cpu
    series, a flagged KS detection held by confirmation, grouped into a confirmed regression."""
    with session_factory(url)() as session:
        good, bad = (
            Revision(
                component_id=component_id,
                title=f"r{2 * number + k}",
                sort_key=str(2 * number + k),
                order_key=order_key(str(2 * number + k)),
            )
            for k in (1, 2)
        )
        series = Series(
            component_id=component_id,
            case="bench",
            phase=f"p{number}",
            params="{}",
            process="component",
            counter="cpu",
        )
        session.add_all([good, bad, series])
        session.flush()
        regression = Regression(
            component_id=component_id,
            good_revision_id=good.id,
            bad_revision_id=bad.id,
            good_key=good.order_key,
            bad_key=bad.order_key,
            state=RegressionState.new,
            confirmation="confirmed",
            confirmation_reason="held over the later revisions",
        )
        session.add(regression)
        session.flush()
        session.add(
            Detection(
                series_id=series.id,
                revision_id=bad.id,
                baseline_revision_id=good.id,
                baseline_revisions=1,
                method="ks",
                verdict="change",
                score=0.9,
                p_value=1e-9,
                effect=0.25,
                direction="increase",
                flagged=True,
                confirmation="held",
                regression_id=regression.id,
            )
        )
        session.commit()
        return datetime.now(UTC)


def worker(env: dict[str, str], log: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [redline_executable(), "worker", *args],
        env=env,
        stdout=log.open("ab"),
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )


def quantile(values: list[float], q: float) -> float:
    return statistics.quantiles(values, n=100)[int(q) - 1] if len(values) > 1 else values[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--regressions", type=int, default=1000)
    parser.add_argument("--components", type=int, default=100)
    parser.add_argument("--subscriptions", type=int, default=100)
    parser.add_argument(
        "--outage",
        type=float,
        default=20.0,
        help="seconds the failing half fails, from the first regression (the run lasts "
        "regressions / rate seconds: 100 by default, so --outage 50 covers half of it)",
    )
    parser.add_argument("--rate", type=float, default=10.0, help="regressions detected per second")
    parser.add_argument(
        "--drain", type=float, default=600.0, help="most seconds to wait at the end"
    )
    parser.add_argument("--logs", type=Path, help="keep the workers' logs in this folder")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    failing = set(range(0, args.subscriptions, 2))
    receivers = Receivers(failing)
    with ExitStack() as stack:
        url = stack.enter_context(database())
        redis = redis_url(stack)
        tmp = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="redline-bench-")))
        logs = args.logs or tmp
        logs.mkdir(parents=True, exist_ok=True)
        queue = f"bench-{uuid.uuid4().hex[:8]}"
        env = dict(
            os.environ,
            REDLINE_DATABASE_URL=url,
            REDLINE_REDIS_URL=redis,
            REDLINE_QUEUE=queue,
            REDLINE_STORAGE_DIR=str(tmp / "storage"),
        )
        components = setup(url, args, receivers)
        reference = []
        with http_client(1) as client:  # the same client as a delivery's
            for _ in range(50):
                started = time.perf_counter()
                client.post(f"{receivers.url}/r1", content=b"{}")
                reference.append(time.perf_counter() - started)
        children = [
            worker(env, logs / "analysis.log", "--queues", "analysis", "--concurrency", "1"),
            worker(
                env, logs / "alerts.log", "--queues", "alerts", "--concurrency", "2", "--no-beat"
            ),
        ]
        for child in children:
            stack.callback(child.wait, 30)
            stack.callback(os.killpg, child.pid, signal.SIGTERM)
        celery = celery_client(Settings(redis_url=redis, queue=queue, database_url=url))
        deadline = time.time() + 120  # both workers up: a task sent earlier waits in the queue
        while not all("ready." in (logs / f"{n}.log").read_text() for n in ("analysis", "alerts")):
            if time.time() > deadline:
                raise SystemExit(f"the workers did not start; see {logs}")
            time.sleep(0.2)
        receivers.until = time.time() + args.outage
        detected: dict[int, float] = {}
        began = time.time()
        for number in range(args.regressions):
            component = components[number % len(components)]
            at = detect(url, component, number)
            celery.send_task(SCAN_ALERTS_TASK, args=[component, None])
            detected[number] = at.timestamp()
            time.sleep(max(0.0, began + (number + 1) / args.rate - time.time()))
        produced = time.time() - began
        expected = args.regressions * (args.subscriptions // args.components)
        with session_factory(url)() as session:
            deadline = time.time() + args.drain
            while time.time() < deadline:
                stored = session.scalar(select(func.count()).select_from(Delivery))
                left = session.scalar(
                    select(func.count())
                    .select_from(Delivery)
                    .where(Delivery.state.in_(("pending", "sending")))
                )
                session.rollback()
                if stored == expected and not left:
                    break
                time.sleep(1.0)
            rows = session.execute(
                select(
                    Delivery.uid,
                    Delivery.state,
                    Delivery.attempts,
                    Delivery.payload,
                    Subscription.url,
                ).join(Subscription, Subscription.id == Delivery.subscription_id)
            ).all()
        delays: dict[str, list[float]] = {"healthy": [], "failing_at_first": []}
        twice = never = 0
        for uid, _state, _, payload, target in rows:
            answers = receivers.ok.get(uid, [])
            twice += len(answers) > 1
            never += not answers
            phase = payload["changes"][0]["phase"]
            number = int(phase[1:])
            kind = "failing_at_first" if int(target.rsplit("/r", 1)[1]) in failing else "healthy"
            if answers:
                delays[kind].append(answers[0] - detected[number])
        floor = statistics.median(reference)
        result = {
            "regressions": args.regressions,
            "subscriptions": args.subscriptions,
            "deliveries_expected": expected,
            "deliveries_stored": len(rows),
            "delivered": sum(1 for r in rows if r[1] == "delivered"),
            "failed": sum(1 for r in rows if r[1] == "failed"),
            "answered_2xx_more_than_once": twice,
            "never_answered_2xx": never,
            "tries_received": receivers.tries,
            "outage_s": args.outage,
            "production_s": round(produced, 1),
            "outage_share_of_production": round(args.outage / produced, 2),
            "reference_post_ms": round(floor * 1000, 2),
        }
        for kind, values in delays.items():
            if values:
                result[f"{kind}_p50_s"] = round(quantile(values, 50), 2)
                result[f"{kind}_p95_s"] = round(quantile(values, 95), 2)
                result[f"{kind}_p50_over_reference"] = round(quantile(values, 50) / floor, 1)
    print(json.dumps(result) if args.json else json.dumps(result, indent=2))
    sys.exit(0 if twice == 0 and never == 0 else 1)


if __name__ == "__main__":
    main()
