"""`redline up`'s supervisor: no secret in a process list or log, and stopping it mid-run leaves
no process behind and loses no job."""

from __future__ import annotations

import os
import time
import uuid
from pathlib import Path

import httpx
import psutil
import pytest
from redline.agent.network import free_port
from redline.commands import demo
from redline.commands.stack import Stack, server_only_variables

from tests.support.servers import Services, fresh_database

pytestmark = pytest.mark.slow


def _started_under(folder: Path) -> list[psutil.Process]:
    """Live processes working in ``folder`` or naming a file in it: the run's component (its
    work tree is there), recorder (its recording is there) and the stack's own children."""
    found = []
    for process in psutil.process_iter(["cwd", "cmdline"]):
        try:
            words = [process.info["cwd"] or "", *(process.info["cmdline"] or [])]
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
        if process.pid != os.getpid() and any(str(folder) in word for word in words):
            found.append(process)
    return found


def _wait_for(condition, timeout: float, what: str) -> None:  # noqa: ANN001
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.3)


@pytest.fixture
def stack(services: Services, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Stack:
    """A stack, not yet started, on a database and a queue of its own."""
    database_url, _ = fresh_database(services.database_url)
    monkeypatch.setenv("REDLINE_DATABASE_URL", database_url)
    monkeypatch.setenv("REDLINE_REDIS_URL", services.redis_url)
    monkeypatch.setenv("REDLINE_QUEUE", f"stack-{uuid.uuid4().hex[:8]}")
    return Stack(tmp_path / "data", free_port())


def _no_secret_in_process_lists(stack: Stack) -> list[str]:
    """No token in any command line under the stack (every user reads those in ps), the
    component's and recorder's included; the agent's environment holds its own token and none of
    the server's settings. Returns the secrets, for the logs to be searched after the stop."""
    secrets = [stack.admin_token, stack.token("agent", "agent")]
    commands = [" ".join(psutil.Process(c.process.pid).cmdline()) for c in stack.children]
    assert len(commands) == 4 and "agent" in commands[-1]  # server, 2 workers, agent
    assert any("--queues alerts" in c for c in commands)  # deliveries apart from analysis
    everything = []
    for process in _started_under(stack.data):
        try:
            everything.append(" ".join(process.cmdline()))
        except psutil.NoSuchProcess:  # ended meanwhile
            continue
    assert not [c for c in [*commands, *everything] if any(secret in c for secret in secrets)]
    # the agent (whose builds and components inherit its environment) holds none of the
    # server's settings: not its database, Redis, storage or secrets
    agent = psutil.Process(stack.children[-1].process.pid).environ()
    assert agent["REDLINE_TOKEN"] == stack.token("agent", "agent")
    # and its token acts for its own host only: another host's name is refused
    forged = httpx.post(
        f"{stack.url}/api/v1/agent/register",
        json={"name": "perf-evil", "labels": []},
        headers={"Authorization": f"Bearer {agent['REDLINE_TOKEN']}"},
    )
    assert forged.status_code == 403, forged.text
    assert "REDLINE_DATABASE_URL" in stack.env and "REDLINE_REDIS_URL" in stack.env
    assert not {k for k in agent if k in server_only_variables()}, sorted(agent)
    page = httpx.get(f"{stack.url}/components/nothing?token={stack.admin_token}")
    assert page.status_code == 404
    _wait_for(
        lambda: "/components/nothing" in (stack.data / "logs" / "server.log").read_text(),
        20,
        "the request in the access log",
    )
    return secrets


def _no_secret_in_logs(stack: Stack, secrets: list[str]) -> None:
    """The logs readable by their owner only, no secret in them, a token in an address
    redacted."""
    logs = stack.data / "logs"
    assert stack.data.stat().st_mode & 0o777 == 0o700  # made by the stack: its owner's only
    assert logs.stat().st_mode & 0o777 == 0o700
    for log in logs.iterdir():
        assert log.stat().st_mode & 0o777 == 0o600, log
        assert not [s for s in secrets if s in log.read_text()], log
    assert "token=***" in (logs / "server.log").read_text()


def test_secrets_stay_hidden_and_stopping_mid_run_leaves_no_process_or_lost_job(
    stack: Stack, tmp_path: Path
):
    """One stack (each start costs the suite seconds): while a run is under way no secret is in
    a process list; stopped mid-run, no process is left, the logs hold no secret, and the job
    is found again by the next start."""
    try:
        stack.start()
        repo = tmp_path / "repo"
        first = demo.make_history(repo)[0]
        demo.submit(stack.url, stack.admin_token, stack.token("ci", "ci"), repo, [first])
        children = {child.process.pid for child in stack.children}
        _wait_for(
            lambda: len({p.pid for p in _started_under(stack.data)} - children) >= 2,
            120,
            "the run's component and recorder",
        )
        secrets = _no_secret_in_process_lists(stack)
    finally:
        stack.stop()
    assert [p.cmdline() for p in _started_under(stack.data) if p.is_running()] == []
    _no_secret_in_logs(stack, secrets)

    restarted = Stack(tmp_path / "data", free_port())
    try:
        restarted.start()
        detail = httpx.get(
            f"{restarted.url}/api/v1/components/objectbuilder/revisions/{first.title}"
        ).json()
        assert [job["state"] for job in detail["jobs"]] in (
            ["queued"],
            ["leased"],
            ["running"],
            ["uploaded"],
            ["done"],
        ), detail
    finally:
        restarted.stop()
