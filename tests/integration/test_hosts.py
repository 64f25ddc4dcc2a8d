"""Redline on three "hosts" (issue 16): network namespaces on this machine, joined to it by veth
pairs. This host runs Postgres, Redis and the API; one namespace runs two Celery workers, which
reach Postgres and Redis over the network; another runs three agents, which reach the API over
the network. A history of revisions goes through while one agent is SIGKILLed mid-job and one
worker is SIGKILLed while it holds a task: every job ends with exactly one execution, the task
the worker held is run by the other, and the verdicts the workers stored (decided ones: the
component answers the suite's queries, so its round trips and CPU are judged) are those detection
on one host gives for the same data, judging it revision by revision: the killed agent's
revision, run again last, has the later revisions judged again in order (`redline.worker.onward`).

The machine is shared with other tests: waits give up when nothing moved for minutes, not after a
fixed time, and say what every process was doing (`tests.support.progress`); leases and the
broker's visibility timeout leave a loaded machine room; and a host busy with other tests does
not keep a phase from being judged, nor make the agents run it again.

Skipped, saying why, where network namespaces cannot be made (not root, no `ip netns`).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import httpx
import pytest
from redline.agent.network import free_port
from redline.detect.result import NOT_ENOUGH_DATA
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
from tests.support.progress import MOST_S, Progress, task_events
from tests.support.servers import Services, fresh_database
from tests.support.tiny import agent_args, tiny_repo

# the waits' own bound (progress.MOST_S), not the suite's 300 s per test, ends a slow run
pytestmark = [pytest.mark.slow, pytest.mark.timeout(3 * MOST_S)]

REDLINE = str(Path(sys.executable).parent / "redline")
REVISIONS = 6
# a killed agent's job goes back to the queue this soon; a live agent renews its lease every
# third of it, so only an agent or API starved for all of it loses its job (4 s asked a loaded
# host never to starve one for 4 s; a job whose lease lapses three times fails)
LEASE_S = 15
VISIBILITY_S = 15  # a killed worker's task, likewise; a live worker's longer task runs twice
#: other load, in % of a core, over which a phase is not judged (and run again): never, here
NEVER_BUSY = {"REDLINE_DISTURBED_CPU_PERCENT": "1000000"}


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
    repo, _ = tiny_repo(tmp_path / "repo", answering=True)
    commits = empty_commits(repo, REVISIONS)  # one commit of one code per revision
    with session_factory(database_url)() as session:
        tokens = {scope: issue_token(session, scope, scope)[1] for scope in ("admin", "ci")}
        agent_tokens = {  # each host's own, bound to its name
            name: issue_token(session, name, "agent", name)[1]
            for name in ("slow-3", "fast-1", "fast-2")
        }
    queue = f"hosts-{uuid.uuid4().hex[:8]}"
    shared = {
        **os.environ,
        **NEVER_BUSY,
        "REDLINE_QUEUE": queue,
        "REDLINE_STORAGE_DIR": str(tmp_path / "storage"),  # a volume every host mounts
        "PYTHONUNBUFFERED": "1",
    }
    logs = tmp_path / "logs"
    logs.mkdir()
    progress = Progress(database_url, logs)
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
        stdout=(logs / "api.log").open("ab"),
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
        **NEVER_BUSY,
        "REDLINE_ALLOW_FILE_REPOS": "true",  # the tiny repository is a folder every host sees
        "PYTHONUNBUFFERED": "1",
    }
    children: list[subprocess.Popen] = [api]
    try:
        progress.until(lambda: _answers(f"http://127.0.0.1:{port}/healthz", api), "the API")
        workers = [
            workers_host.popen(
                [REDLINE, "worker", "--no-beat", "--concurrency", "1", "--queues", "analysis"],
                logs / f"worker-{index}.log",
                worker_env,
            )
            for index in (1, 2)
        ]
        children += workers
        agents: dict[str, subprocess.Popen] = {}

        def start(*names: str) -> None:
            for name in names:
                argv = [REDLINE, *agent_args(server, name, tmp_path / name)]
                env = {**agent_env, "REDLINE_TOKEN": agent_tokens[name]}
                agents[name] = agents_host.popen(argv, logs / f"{name}.log", env)
                children.append(agents[name])

        start("slow-3")  # slow-*: its build hangs (tiny.py)
        history = _History(f"http://127.0.0.1:{port}", tokens, repo, commits)
        history.report(1)  # r1 alone: the slow agent holds the oldest revision, run last
        held = progress.until(lambda: _held_by(database_url, "slow-3"), "the slow agent runs a job")
        start("fast-1", "fast-2")
        history.report(2, REVISIONS)
        progress.until(lambda: _done(database_url) >= 1, "a first execution of a fast agent")
        os.killpg(agents["slow-3"].pid, signal.SIGKILL)  # mid-job: its lease will lapse
        task = progress.until(lambda: _kill_holding(workers[0], logs / "worker-1.log"),
                              "the first worker holding a task, killed")  # fmt: skip
        progress.until(lambda: _done(database_url) == REVISIONS, "every job ingested")
        progress.until(
            lambda: task_events(logs / "worker-2.log").get(task) == "succeeded",
            f"task {task}, held by the killed worker, run by the other",
        )
        progress.until(lambda: _quiet(database_url, services.redis_url, queue),
                       "the detections after the last ingestion")  # fmt: skip
        os.killpg(workers[1].pid, signal.SIGTERM)  # it finishes what it runs, then stops
        workers[1].wait(timeout=120)
        _check(database_url, held)
    except BaseException:
        if not progress.reported:  # what every process was doing, which tmp_path will not keep
            print(progress.report())
        raise
    finally:
        for child in children:
            if child.poll() is None:
                os.killpg(child.pid, signal.SIGKILL)
                child.wait(timeout=30)
        database_relay.close()
        redis_relay.close()


class _History:
    """The tiny component, and one revision per commit as CI reports them."""

    def __init__(self, url: str, tokens: dict[str, str], repo: Path, commits: list[str]) -> None:
        self.url, self.tokens, self.commits = url, tokens, commits
        httpx.post(
            f"{url}/api/v1/components",
            headers={"Authorization": f"Bearer {tokens['admin']}"},
            json={"name": "tiny", "repo": str(repo), "suite": "perf/redline.toml"},
            timeout=60,
        ).raise_for_status()
        # no confirmation runs: this test's subject is leases and late results across hosts,
        # and a run pinned to the killed agent's host would wait for it (confirmation runs on
        # real agents: test_end_to_end; their bad input: test_confirmation_runs)
        httpx.put(
            f"{url}/api/v1/components/tiny/detection-config",
            headers={"Authorization": f"Bearer {tokens['admin']}"},
            json={"confirm_pairs": 0, "reanalyze": False},
            timeout=60,
        ).raise_for_status()

    def report(self, first: int, last: int | None = None) -> None:
        """Revisions r<first> to r<last> (agents lease the newest first)."""
        for number in range(first, (last or first) + 1):
            httpx.post(
                f"{self.url}/api/v1/revisions",
                headers={"Authorization": f"Bearer {self.tokens['ci']}"},
                json={"component": "tiny", "title": f"r{number}", "sort_key": str(number),
                      "commit": self.commits[number - 1]},
                timeout=60,
            ).raise_for_status()  # fmt: skip


def _no_failed_job(session) -> None:
    failed = session.execute(select(Job.id, Job.reason).where(Job.state == JobState.failed))
    if reasons := list(failed):
        pytest.fail(f"jobs failed: {reasons}")


def _held_by(database_url: str, agent: str) -> int | None:
    with session_factory(database_url)() as session:
        _no_failed_job(session)
        return session.scalar(
            select(Job.id)
            .join(HostRow, HostRow.id == Job.host_id)
            .where(Job.state == JobState.running, HostRow.name == agent)
        )


def _done(database_url: str) -> int:
    with session_factory(database_url)() as session:
        _no_failed_job(session)
        return session.scalar(select(func.count()).where(Job.state == JobState.done)) or 0


def _kill_holding(worker: subprocess.Popen, log: Path) -> str | None:
    """SIGKILL ``worker`` while it holds a task (received, its success not logged, so not
    acknowledged): that task's id; None, and the worker left running, while it holds none."""
    if not [task for task, event in task_events(log).items() if event == "received"]:
        return None
    os.killpg(worker.pid, signal.SIGSTOP)  # its log stands still: is the task still held?
    held = [task for task, event in task_events(log).items() if event == "received"]
    os.killpg(worker.pid, signal.SIGKILL if held else signal.SIGCONT)
    return held[0] if held else None


def _quiet(database_url: str, redis_url: str, queue: str) -> bool:
    """Nothing queued, and every revision judged."""
    import redis

    with redis.Redis.from_url(redis_url) as broker:
        waiting = sum(broker.llen(queue_of_kind) for queue_of_kind in _queues(queue))
    with session_factory(database_url)() as session:
        unjudged = session.scalar(select(func.count()).where(Revision.analyzed_at.is_(None)))
    return waiting == 0 and unjudged == 0


def _check(database_url: str, held: int) -> None:
    """Each job done with one execution, the slow agent's by a fast one, and the stored
    verdicts, decided ones among them, those detection on one host gives."""
    with session_factory(database_url)() as session:
        jobs = session.scalars(select(Job).order_by(Job.id)).all()
        executions = dict(
            session.execute(select(Execution.job_id, func.count()).group_by(Execution.job_id)).all()
        )
        assert [job.state for job in jobs] == [JobState.done] * REVISIONS
        assert all(executions.get(job.id) == 1 for job in jobs), executions  # each once
        replaced = session.get_one(Job, held)
        assert replaced.attempts == 2 and replaced.host is not None
        assert replaced.host.name in ("fast-1", "fast-2")
        order = session.scalars(select(Revision.id).order_by(Revision.order_key)).all()
    stored = _verdicts(database_url)
    decided = {(row[0], row[1]) for row in stored if row[3] != NOT_ENOUGH_DATA}
    # r2.. against their baselines, on more than one series (round trips, the component's CPU)
    assert len({series for _, series in decided}) >= 2, stored
    for revision_id in order:  # the same data judged on one host, revision by revision
        detect_revision(database_url, revision_id)
    judged = _verdicts(database_url)
    assert len(judged) == len(stored)
    differ = [(was, now) for was, now in zip(stored, judged, strict=True) if was != now]
    assert not differ, f"{len(differ)} verdicts differ, the first (stored, one host's): {differ[0]}"


def _answers(url: str, api: subprocess.Popen) -> bool:
    if api.poll() is not None:
        pytest.fail("the API stopped")  # its log's end follows
    try:
        return httpx.get(url, timeout=2).status_code == 200
    except httpx.HTTPError:
        return False


def _queues(prefix: str) -> list[str]:
    from redline.server.core.config import Settings

    settings = Settings(queue=prefix)
    return [queue_of(settings, kind) for kind in QUEUE_KINDS]
