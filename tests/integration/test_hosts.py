"""Redline on three "hosts" (issue 16): network namespaces on this machine, joined to it by veth
pairs. This host runs Postgres, Redis and the API; one namespace runs two Celery workers, which
reach Postgres and Redis over the network; another runs three agents, which reach the API over
the network. A history of revisions goes through while one agent is SIGKILLed mid-job and one
worker is SIGKILLed while ingestions flow: every job ends with exactly one execution, and the
verdicts the workers stored are those detection on one host gives for the same data.

Skipped, saying why, where network namespaces cannot be made (not root, no `ip netns`).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import httpx
import pytest
from redline.agent.network import free_port
from redline.server.core.tasks import QUEUE_KINDS, queue_of
from redline.server.db import migrate, session_factory
from redline.server.models import Detection, Execution, Job, JobState, Revision
from redline.server.models import Host as HostRow
from redline.server.services.tokens import issue_token
from redline.worker.detection import detect_revision
from sqlalchemy import func, select
from sqlalchemy.engine import make_url

from tests.support.git import empty_commits
from tests.support.netns import Host, Relay, why_not_allowed
from tests.support.servers import Services, fresh_database
from tests.support.tiny import agent_args, tiny_repo

pytestmark = pytest.mark.slow

REDLINE = str(Path(sys.executable).parent / "redline")
REVISIONS = 6
LEASE_S = 4  # a killed agent's job goes back to the queue this soon
VISIBILITY_S = 4  # and a killed worker's task


def _until(check: Callable[[], object], what: str, timeout: float = 150.0) -> object:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if found := check():
            return found
        time.sleep(0.3)
    pytest.fail(f"gave up waiting: {what}")


def _database_relay(url: str, gateway: str) -> tuple[Relay, str]:
    """A relay to the database of ``url``, and the URL another host reaches it at."""
    parsed = make_url(url)
    socket_dir = parsed.query.get("host")
    if isinstance(socket_dir, str) and socket_dir.startswith("/"):
        relay = Relay(f"{socket_dir}/.s.PGSQL.{parsed.port or 5432}")
    else:
        relay = Relay((parsed.host or "127.0.0.1", parsed.port or 5432))
    remote = parsed.difference_update_query(["host"]).set(host=gateway, port=relay.port)
    return relay, remote.render_as_string(hide_password=False)


def _redis_relay(url: str, gateway: str) -> tuple[Relay, str]:
    parsed = urlsplit(url)
    if parsed.scheme == "unix":
        relay, db = Relay(parsed.path), parse_qs(parsed.query).get("db", ["0"])[0]
    else:
        relay, db = Relay((parsed.hostname or "127.0.0.1", parsed.port or 6379)), "0"
        db = parsed.path.lstrip("/") or db
    return relay, f"redis://{gateway}:{relay.port}/{db}"


@pytest.fixture
def hosts() -> Iterator[tuple[Host, Host]]:
    if reason := why_not_allowed():
        pytest.skip(reason)
    workers, agents = Host("workers", 1), Host("agents", 2)
    for host in (workers, agents):
        host.create()
    yield workers, agents
    for host in (workers, agents):
        host.delete()


def _verdicts(database_url: str) -> list[tuple]:
    with session_factory(database_url)() as session:
        return [
            tuple(row)
            for row in session.execute(
                select(
                    Revision.title,
                    Detection.series_id,
                    Detection.method,
                    Detection.verdict,
                    Detection.reason,
                    Detection.score,
                    Detection.baseline_revision_id,
                )
                .join(Revision, Revision.id == Detection.revision_id)
                .order_by(Revision.title, Detection.series_id, Detection.method)
            )
        ]


def test_three_hosts_lose_no_job_to_a_killed_agent_or_worker(
    services: Services, hosts: tuple[Host, Host], tmp_path: Path
) -> None:
    workers_host, agents_host = hosts
    database_url, _ = fresh_database(services.database_url)
    migrate(database_url)
    repo, _ = tiny_repo(tmp_path / "repo")
    commits = empty_commits(repo, REVISIONS)  # one commit of one code per revision
    with session_factory(database_url)() as session:
        tokens = {scope: issue_token(session, scope, scope)[1] for scope in ("admin", "ci")}
        agent_token = issue_token(session, "agents", "agent")[1]
    queue = f"hosts-{uuid.uuid4().hex[:8]}"
    shared = {
        **os.environ,
        "REDLINE_QUEUE": queue,
        "REDLINE_STORAGE_DIR": str(tmp_path / "storage"),  # a volume every host mounts
        "PYTHONUNBUFFERED": "1",
    }
    port = free_port()
    api = subprocess.Popen(
        [REDLINE, "server", "--host", "0.0.0.0", "--port", str(port)],
        env={
            **shared,
            "REDLINE_DATABASE_URL": database_url,
            "REDLINE_REDIS_URL": services.redis_url,
            "REDLINE_LEASE_SECONDS": str(LEASE_S),
            "REDLINE_ALLOW_FILE_REPOS": "true",
        },
        stdout=(tmp_path / "api.log").open("ab"),
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    database_relay, remote_database = _database_relay(database_url, workers_host.gateway)
    redis_relay, remote_redis = _redis_relay(services.redis_url, workers_host.gateway)
    worker_env = {
        **shared,
        "REDLINE_DATABASE_URL": remote_database,
        "REDLINE_REDIS_URL": remote_redis,
        "REDLINE_TASK_VISIBILITY_S": str(VISIBILITY_S),
    }
    server = f"http://{agents_host.gateway}:{port}"  # the API as the agents' host reaches it
    agent_env = {
        **os.environ,
        "REDLINE_TOKEN": agent_token,
        "REDLINE_ALLOW_FILE_REPOS": "true",  # the tiny repository is a folder every host sees
        "PYTHONUNBUFFERED": "1",
    }
    children: list[subprocess.Popen] = [api]
    try:
        _until(lambda: _answers(f"http://127.0.0.1:{port}/healthz", api, tmp_path), "the API")
        workers = [
            workers_host.popen(
                [REDLINE, "worker", "--no-beat", "--concurrency", "1", "--queues", "analysis"],
                tmp_path / f"worker-{index}.log",
                worker_env,
            )
            for index in (1, 2)
        ]
        children += workers
        agents = {
            name: agents_host.popen(
                [REDLINE, *agent_args(server, name, tmp_path / name)],
                tmp_path / f"{name}.log",
                agent_env,
            )
            for name in ("fast-1", "fast-2", "slow-3")  # slow-*: its build hangs (tiny.py)
        }
        children += agents.values()
        client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30)
        client.post(
            "/api/v1/components",
            headers={"Authorization": f"Bearer {tokens['admin']}"},
            json={"name": "tiny", "repo": str(repo), "suite": "perf/redline.toml"},
        ).raise_for_status()
        for number, commit in enumerate(commits, start=1):
            client.post(
                "/api/v1/revisions",
                headers={"Authorization": f"Bearer {tokens['ci']}"},
                json={"component": "tiny", "title": f"r{number}", "sort_key": str(number),
                      "commit": commit},
            ).raise_for_status()  # fmt: skip

        def held_by_slow() -> int | None:
            with session_factory(database_url)() as session:
                failed = session.scalars(select(Job.reason).where(Job.state == JobState.failed))
                if reasons := list(failed):
                    pytest.fail(f"jobs failed: {reasons}")
                return session.scalar(
                    select(Job.id)
                    .join(HostRow, HostRow.id == Job.host_id)
                    .where(Job.state == JobState.running, HostRow.name == "slow-3")
                )

        held = _until(held_by_slow, "the slow agent runs a job")
        os.killpg(agents["slow-3"].pid, signal.SIGKILL)  # mid-job: its lease will lapse

        def done() -> int:
            with session_factory(database_url)() as session:
                return session.scalar(select(func.count()).where(Job.state == JobState.done)) or 0

        _until(lambda: done() >= 1, "a first execution ingested")
        os.killpg(workers[0].pid, signal.SIGKILL)  # while the others' ingestions flow
        _until(lambda: done() == REVISIONS, "every job ingested, on the worker left")

        def quiet() -> bool:  # nothing queued, and every revision judged
            import redis

            with redis.Redis.from_url(services.redis_url) as broker:
                waiting = sum(broker.llen(queue_of_kind) for queue_of_kind in _queues(queue))
            with session_factory(database_url)() as session:
                unjudged = session.scalar(
                    select(func.count()).where(Revision.analyzed_at.is_(None))
                )
            return waiting == 0 and unjudged == 0

        _until(quiet, "the detections after the last ingestion")
        os.killpg(workers[1].pid, signal.SIGTERM)  # it finishes what it runs, then stops
        workers[1].wait(timeout=60)

        with session_factory(database_url)() as session:
            jobs = session.scalars(select(Job).order_by(Job.id)).all()
            executions = dict(
                session.execute(
                    select(Execution.job_id, func.count()).group_by(Execution.job_id)
                ).all()
            )
            assert [job.state for job in jobs] == [JobState.done] * REVISIONS
            assert all(executions.get(job.id) == 1 for job in jobs), executions  # each once
            replaced = session.get_one(Job, held)
            assert replaced.attempts == 2 and replaced.host is not None
            assert replaced.host.name in ("fast-1", "fast-2")
            order = session.scalars(select(Revision.id).order_by(Revision.order_key)).all()
        stored = _verdicts(database_url)
        assert stored, "the workers judged the history"
        for revision_id in order:  # the same data judged on one host, revision by revision
            detect_revision(database_url, revision_id)
        assert _verdicts(database_url) == stored
    finally:
        for child in children:
            if child.poll() is None:
                os.killpg(child.pid, signal.SIGKILL)
                child.wait(timeout=30)
        database_relay.close()
        redis_relay.close()


def _answers(url: str, api: subprocess.Popen, tmp_path: Path) -> bool:
    if api.poll() is not None:
        pytest.fail(f"the API stopped: {(tmp_path / 'api.log').read_text()[-2000:]}")
    try:
        return httpx.get(url, timeout=2).status_code == 200
    except httpx.HTTPError:
        return False


def _queues(prefix: str) -> list[str]:
    from redline.server.core.config import Settings

    settings = Settings(queue=prefix)
    return [queue_of(settings, kind) for kind in QUEUE_KINDS]
