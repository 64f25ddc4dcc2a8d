"""The agent's job loop against a server stand-in: a job whose lease was lost is not failed."""

from __future__ import annotations

from pathlib import Path

import pytest
from redline.agent.client import LeaseLost
from redline.agent.daemon import AgentDaemon, JobFailed


class _LostLeaseClient:
    """A server that took the job away at the first heartbeat."""

    host = "perf1"

    def __init__(self) -> None:
        self.failed: list[int] = []

    def lease(self, wait: int = 0) -> dict:
        return {
            "id": 7,
            "component": "builder",
            "commit": "abc123",
            "repo": "/src/x.git",
            "suite": "perf/redline.toml",
            "execution_index": 0,
            "revision": {"title": "r1", "sort_key": "1"},
        }

    def heartbeat(self, job_id: int) -> None:
        raise LeaseLost(f"job {job_id} is not leased to host 'perf1'")

    def fail(self, job_id: int, reason: str) -> None:
        self.failed.append(job_id)


@pytest.mark.parametrize("error", [JobFailed("build broke"), OSError("disk full")])
def test_the_agent_does_not_fail_a_job_whose_lease_it_lost(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, error: Exception
):
    client = _LostLeaseClient()
    daemon = AgentDaemon(client=client, workdir=tmp_path)  # type: ignore[arg-type]

    def run(job: dict, name: str) -> Path:
        raise error

    monkeypatch.setattr(daemon, "_run", run)
    assert daemon.run_once() is True
    assert client.failed == []
