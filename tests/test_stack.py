"""`redline up`'s supervisor: stopping it mid-run leaves no process behind and loses no job."""

from __future__ import annotations

import os
import time
import uuid
from pathlib import Path

import httpx
import psutil
import pytest
from redline.server import demo
from redline.server.stack import Stack

from tests.conftest import Services, fresh_database

pytestmark = pytest.mark.integration


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


def test_stopping_mid_run_leaves_no_process_and_releases_the_job(
    services: Services, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    from redline.agent.network import free_port

    database_url, _ = fresh_database(services.database_url)
    monkeypatch.setenv("REDLINE_DATABASE_URL", database_url)
    monkeypatch.setenv("REDLINE_REDIS_URL", services.redis_url)
    monkeypatch.setenv("REDLINE_QUEUE", f"stack-{uuid.uuid4().hex[:8]}")
    stack = Stack(tmp_path / "data", free_port())
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
    finally:
        stack.stop()
    assert [p.cmdline() for p in _started_under(stack.data) if p.is_running()] == []

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
