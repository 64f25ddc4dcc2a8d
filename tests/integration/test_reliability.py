"""Failures on real processes: agents killed or stopped mid-job, the server killed mid-upload,
Postgres gone for a while, and 20 agents racing for 200 jobs.

The server and the agents are `redline server` / `redline agent` child processes started through
`redline.commands.stack`, on real Postgres and Redis. The suite they run is tiny (a component that
idles, one one-second phase) so that a job takes seconds; its build step hangs for agents whose
work folder is named ``slow-*``, which is how a test holds an agent in the middle of a job.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import signal
import subprocess
import tempfile
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import pytest
from redline.agent.client import ServerClient
from redline.agent.network import free_port
from redline.commands.stack import Child, Stack
from redline.recording import read_recording
from redline.server.db import session_factory
from redline.server.models import Execution, Job, JobState, Revision
from redline.server.services.jobs import holder
from redline.server.services.tokens import issue_token
from sqlalchemy import func, select, update

from tests.support.api import commit_of
from tests.support.servers import Services, fresh_database
from tests.support.tiny import agent_args, tiny_repo

pytestmark = pytest.mark.slow

LEASE_S = 4  # short, so that a killed agent's lease lapses within the test
UNTIL_S = 90.0


def _until(check: Callable[[], object], what: str, timeout: float = UNTIL_S) -> object:
    """Poll ``check`` until it returns something true; fail naming ``what`` otherwise."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        result = check()
        if result:
            return result
        time.sleep(0.2)
    pytest.fail(f"gave up waiting: {what}")


@dataclass
class Service:
    """One Redline server process (and agents) over one database, driven like production."""

    stack: Stack
    root: Path
    repo: Path
    commit: str
    tokens: dict[str, str] = field(default_factory=dict)

    @property
    def database_url(self) -> str:
        return self.stack.env["REDLINE_DATABASE_URL"]

    def headers(self, scope: str) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.tokens[scope]}"}

    def agent_token(self, host: str) -> str:
        """The agent token bound to ``host``, issued on first use (in this process: a
        `redline token create` per host cost 2 s each, 40 s for twenty racing agents)."""
        key = f"agent@{host}"
        if key not in self.tokens:
            with session_factory(self.database_url)() as session:
                self.tokens[key] = issue_token(session, host, "agent", host)[1]
        return self.tokens[key]

    def start_server(self) -> None:
        self.stack._spawn("server", "server", "--host", "127.0.0.1", "--port", str(self.stack.port))
        self.stack._wait_healthy()

    def start_agent(self, name: str) -> Child:
        self.stack._spawn(
            name,
            *agent_args(self.stack.url, name, self.root / name),
            env={"REDLINE_TOKEN": self.agent_token(name)},
        )
        return self.stack.children[-1]

    def kill(self, child: Child, signum: int = signal.SIGKILL) -> None:
        """Signal the child's whole process group (its build and run processes too) and reap."""
        os.killpg(child.process.pid, signum)
        child.process.wait(timeout=60)
        child.log.close()
        self.stack.children.remove(child)

    def job(self, component: str, title: str = "r1") -> int:
        """Register ``component`` on the tiny repository and report one revision: its job id."""
        answer = httpx.post(
            f"{self.stack.url}/api/v1/components",
            headers=self.headers("admin"),
            json={"name": component, "repo": str(self.repo), "suite": "perf/redline.toml"},
        )
        assert answer.status_code in (201, 409), answer.text
        answer = httpx.post(
            f"{self.stack.url}/api/v1/revisions",
            headers=self.headers("ci"),
            json={
                "component": component,
                "title": title,
                "sort_key": "1",
                "commit": self.commit,
                "repo": str(self.repo),
            },
        )
        assert answer.status_code == 201, answer.text
        with session_factory(self.database_url)() as session:
            return session.scalars(select(Job.id).order_by(Job.id.desc())).first() or 0

    def row(self, job_id: int) -> Job:
        with session_factory(self.database_url)() as session:
            job = session.get_one(Job, job_id)
            _ = job.host
            return job

    def executions(self, job_id: int) -> int:
        with session_factory(self.database_url)() as session:
            return (
                session.scalar(
                    select(func.count()).select_from(Execution).where(Execution.job_id == job_id)
                )
                or 0
            )

    def stop_agents(self) -> None:
        for child in [c for c in self.stack.children if c.name != "server"]:
            if child.process.poll() is None:
                self.kill(child)
            else:
                child.log.close()
                self.stack.children.remove(child)
        with session_factory(self.database_url)() as session:  # nothing left for the next test
            session.execute(
                update(Job)
                .where(Job.state.in_(["queued", "leased", "running"]))
                .values(state=JobState.cancelled)
            )
            session.commit()


def _service(database_url: str, redis_url: str, root: Path, lease_s: int) -> Service:
    repo, commit = tiny_repo(root / "tiny-repo")
    stack = Stack(root / "data", free_port())
    (stack.data / "logs").mkdir(parents=True, exist_ok=True)
    stack.env = dict(
        os.environ,
        REDLINE_DATABASE_URL=database_url,
        REDLINE_REDIS_URL=redis_url,
        REDLINE_STORAGE_DIR=str(root / "storage"),
        REDLINE_LEASE_SECONDS=str(lease_s),
        REDLINE_QUEUE=f"rel-{uuid.uuid4().hex[:8]}",
        PYTHONUNBUFFERED="1",
        REDLINE_WEBHOOK_SECRET="the-real-secret",
        REDLINE_ALLOW_FILE_REPOS="true",
    )
    stack._redline("migrate")
    service = Service(stack, root, repo, commit)
    service.tokens = {scope: stack.token(scope, scope) for scope in ("admin", "ci")}
    service.start_server()
    return service


@pytest.fixture(scope="module")
def shared(services: Services, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    database_url, _ = fresh_database(services.database_url)
    service = _service(database_url, services.redis_url, tmp_path_factory.mktemp("rel"), LEASE_S)
    yield service
    service.stack.stop()


@pytest.fixture
def service(shared: Service) -> Iterator[Service]:
    if not any(c.name == "server" for c in shared.stack.children):
        shared.start_server()
    yield shared
    shared.stop_agents()


def _unread_by_server(port: int) -> int:
    """Bytes that have arrived for the server listening on 127.0.0.1:``port`` and that it has
    not read yet: the receive queues of its established connections (/proc/net/tcp)."""
    unread = 0
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        _, local, _, state, queues, *_ = line.split()
        if int(local.rsplit(":", 1)[1], 16) == port and state == "01":  # ESTABLISHED
            unread += int(queues.split(":")[1], 16)
    return unread


def _holder(service: Service, job_id: int, host: str) -> bool:
    job = service.row(job_id)
    return job.state == JobState.running and job.host is not None and job.host.name == host


def test_agent_killed_mid_job_is_replaced_after_its_lease_lapses_and_one_execution_is_stored(
    service: Service,
):
    job_id = service.job("killed")
    slow = service.start_agent("slow-killed")
    _until(lambda: _holder(service, job_id, "slow-killed"), "the slow agent runs the job")
    service.kill(slow)
    service.start_agent("fast-after-kill")
    _until(lambda: service.row(job_id).state == JobState.uploaded, "the job's recording stored")
    job = service.row(job_id)
    assert job.host is not None and job.host.name == "fast-after-kill"
    assert job.attempts == 2
    assert service.executions(job_id) == 1


def test_second_sigterm_releases_the_job_without_counting_an_attempt(service: Service):
    job_id = service.job("released")
    agent = service.start_agent("slow-released")
    _until(lambda: _holder(service, job_id, "slow-released"), "the slow agent runs the job")
    agent.process.send_signal(signal.SIGTERM)
    # two signals sent at once may arrive as one: the second follows the agent's answer
    _until(lambda: "then stopping" in agent.tail(), "the agent acknowledges the first SIGTERM")
    agent.process.send_signal(signal.SIGTERM)
    assert agent.process.wait(timeout=60) == 0, agent.tail()
    job = service.row(job_id)
    assert (job.state, job.attempts, holder(job)) == (JobState.queued, 0, None), agent.tail()


def test_an_agent_gone_during_its_long_poll_is_leased_nothing(service: Service):
    """A killed agent's long poll went on at the server and leased the next job queued to no
    one: the next agent could not run it until the lease lapsed (CI saw the test above fail
    on the job its predecessor's killed agent had been leased)."""
    client = ServerClient(service.stack.url, service.agent_token("gone"), "gone")
    client.register({}, [])
    wait_s = 2
    with pytest.raises(httpx.ReadTimeout):  # the agent goes away: its connection closes
        client._http.post(
            "/api/v1/agent/lease",
            json={"host": "gone"},
            params={"wait": wait_s},
            timeout=httpx.Timeout(10, read=0.3),
        )
    job_id = service.job("abandoned")
    time.sleep(wait_s + 1)  # the poll's end at the latest: it would have leased the job by then
    job = service.row(job_id)
    assert (job.state, job.attempts, holder(job)) == (JobState.queued, 0, None)


def test_one_sigterm_lets_the_agent_finish_its_job_then_stop(service: Service):
    job_id = service.job("finished")
    agent = service.start_agent("fast-finishing")
    _until(lambda: _holder(service, job_id, "fast-finishing"), "the agent runs the job")
    agent.process.send_signal(signal.SIGTERM)
    assert agent.process.wait(timeout=120) == 0, agent.tail()
    assert service.row(job_id).state == JobState.uploaded, agent.tail()
    assert service.executions(job_id) == 1
    # the component's output reached the server in its recording; the agent's token did not
    # reach the component (whose output readers of the server's pages see)
    with session_factory(service.database_url)() as session:
        stored = session.scalars(select(Execution).where(Execution.job_id == job_id)).one()
        recording = read_recording(stored.recording_path)
    assert recording.logs["tiny"] == ("tiny ready; the agent's token in my environment: False\n"), (
        recording.logs
    )


def test_server_killed_during_an_upload_the_agent_retries_and_it_is_stored_once(service: Service):
    job_id = service.job("restarted")
    agent = service.start_agent("fast-restart")
    server = next(c for c in service.stack.children if c.name == "server")
    _until(lambda: _holder(service, job_id, "fast-restart"), "the agent runs the job")
    server.process.send_signal(signal.SIGSTOP)  # frozen: the upload that comes next hangs
    spooled = service.root / "fast-restart" / "spool" / f"job-{job_id}.mcap"
    size = _until(lambda: spooled.exists() and spooled.stat().st_size, "the recording spooled")
    _until(  # the upload is in the frozen server's socket (a heartbeat is a few hundred bytes)
        lambda: _unread_by_server(service.stack.port) >= min(int(size), 16_384),
        "the upload reaches the frozen server",
    )
    service.kill(server)
    service.start_server()
    _until(lambda: not spooled.exists(), "the spooled recording is accepted", timeout=120)
    assert service.executions(job_id) == 1, agent.tail()
    assert service.row(job_id).state == JobState.uploaded


def test_twenty_agents_leasing_two_hundred_jobs_over_http_lease_each_exactly_once(service: Service):
    """Over HTTP to a server process whose leases outlast the race."""
    second = Stack(service.root / "data2", free_port())
    second.env = dict(service.stack.env, REDLINE_LEASE_SECONDS="600")
    (second.data / "logs").mkdir(parents=True, exist_ok=True)
    second._spawn("server", "server", "--host", "127.0.0.1", "--port", str(second.port))
    try:
        second._wait_healthy()
        ids = _two_hundred_jobs(service)
        hosts = [f"racer-{n:02d}" for n in range(20)]
        tokens = {host: service.agent_token(host) for host in hosts}
        with ThreadPoolExecutor(len(hosts)) as pool:  # the long-lease server: none may lapse
            leased = list(pool.map(lambda host: _race(second.url, host, tokens[host]), hosts))
    finally:
        second.stop()
    counts = Counter(job_id for mine in leased for job_id in mine)
    assert set(counts) == set(ids) and set(counts.values()) == {1}, counts.most_common(3)
    assert sum(1 for mine in leased if mine) > 1  # the race had more than one winner


def test_forged_webhook_signature_to_the_server_process_is_401_and_creates_nothing(
    service: Service,
):
    service.job("hooked")
    push = json.dumps(
        {
            "ref": "refs/heads/main",
            "repository": {"clone_url": str(service.repo)},
            "commits": [
                {"id": "f" * 40, "message": "forged", "timestamp": "2026-11-22T03:00:00+00:00"}
            ],
        }
    ).encode()
    forged = "sha256=" + hmac.new(b"guessed", push, hashlib.sha256).hexdigest()
    with session_factory(service.database_url)() as session:
        before = session.scalar(select(func.count()).select_from(Revision))
    answer = httpx.post(
        f"{service.stack.url}/api/v1/webhooks/github",
        content=push,
        headers={
            "X-Hub-Signature-256": forged,
            "X-GitHub-Event": "push",
            "Content-Type": "application/json",
        },
    )
    assert answer.status_code == 401, answer.text
    with session_factory(service.database_url)() as session:
        assert session.scalar(select(func.count()).select_from(Revision)) == before


def _two_hundred_jobs(service: Service) -> list[int]:
    answer = httpx.post(
        f"{service.stack.url}/api/v1/components",
        headers=service.headers("admin"),
        # a folder that is there (a local repository must be); its jobs are leased, never run
        json={"name": "raced", "repo": str(service.root), "suite": "s.toml", "executions": 10},
    )
    assert answer.status_code == 201, answer.text
    for n in range(20):
        answer = httpx.post(
            f"{service.stack.url}/api/v1/revisions",
            headers=service.headers("ci"),
            json={
                "component": "raced",
                "title": f"r{n}",
                "sort_key": str(n),
                "commit": commit_of(f"r{n}"),
            },
        )
        assert answer.status_code == 201, answer.text
    with session_factory(service.database_url)() as session:
        ids = list(session.scalars(select(Job.id).where(Job.state == JobState.queued)))
    assert len(ids) == 200
    return ids


def _race(url: str, host: str, token: str) -> list[int]:
    client = ServerClient(url, token, host)
    try:
        client.register({}, [])
        mine = []
        while (job := client.lease()) is not None:
            mine.append(int(job["id"]))
        return mine
    finally:
        client.close()


@pytest.fixture
def own_postgres(services: Services, tmp_path: Path) -> Iterator[tuple[str, Callable, Callable]]:
    """An embedded Postgres this test may stop and start (not the shared one)."""
    from redline.commands.embedded import start_postgres

    folder = Path(tempfile.mkdtemp(prefix="redline-test-pgdown-"))
    url, handle = start_postgres(folder / "data", "redline")
    handles = [handle]

    def stop() -> None:
        handles.pop().cleanup()

    def start() -> None:
        again, handle = start_postgres(folder / "data", "redline")
        assert again == url
        handles.append(handle)

    try:
        yield url, stop, start
    finally:
        for handle in handles:
            handle.cleanup()
        subprocess.run(["rm", "-rf", str(folder)], check=False)


def test_postgres_away_the_api_answers_503_agents_spool_and_nothing_is_lost(
    own_postgres: tuple[str, Callable, Callable], services: Services, tmp_path: Path
):
    url, stop_postgres, start_postgres = own_postgres
    service = _service(url, services.redis_url, tmp_path, lease_s=120)
    try:
        job_id = service.job("spooled")
        agent = service.start_agent("fast-spooling")
        _until(lambda: _holder(service, job_id, "fast-spooling"), "the agent runs the job")
        stop_postgres()
        health = httpx.get(f"{service.stack.url}/healthz")
        assert health.status_code == 503 and health.json()["status"] == "unavailable"
        lease = httpx.post(
            f"{service.stack.url}/api/v1/agent/lease",
            headers={"Authorization": f"Bearer {service.agent_token('fast-spooling')}"},
            json={"host": "fast-spooling"},
        )
        assert lease.status_code == 503, lease.text
        assert "database is unavailable" in lease.json()["detail"]
        logged = (service.stack.data / "logs" / "server.log").read_text()
        assert "POST /api/v1/agent/lease: 503, the database: " in logged  # why, not only that
        spooled = tmp_path / "fast-spooling" / "spool" / f"job-{job_id}.mcap"
        _until(
            lambda: spooled.exists() and "recording spooled" in agent.tail(40),
            "the agent spools its recording",
        )
        start_postgres()
        _until(lambda: not spooled.exists(), "the spooled recording is accepted", timeout=120)
        assert httpx.get(f"{service.stack.url}/healthz").json()["database"] == "ok"
        assert service.executions(job_id) == 1, agent.tail()
        assert service.row(job_id).state == JobState.uploaded
    finally:
        service.stack.stop()
