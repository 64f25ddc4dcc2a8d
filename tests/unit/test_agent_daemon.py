"""The agent's job loop against a server stand-in: a job whose lease was lost is not failed; an
execution the host was busy in is run again, boundedly, and says so."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from redline.agent import daemon as daemon_module
from redline.agent.client import LeaseLost
from redline.agent.daemon import AgentDaemon, JobFailed
from redline.agent.runner import RunResult
from redline.recording import read_recording

from tests.support.git import committed_repo
from tests.support.recordings import write_recording


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


SUITE_FILES = {
    "perf/redline.toml": 'name = "s"\ntests = ["test_s.py"]\n[[component]]\nname = "c"\n'
    'command = ["python", "c.py"]\nready = { log = "ready" }\n',
    "perf/c.py": "print('ready')\n",
    "perf/test_s.py": "from redline.testing import Phase, Sleep, TestCase\n"
    "case = TestCase('idle', [Phase('idle', Sleep(0.1))])\n",
}


@pytest.mark.parametrize(
    ("busy", "retries", "runs", "matters"),
    [
        ((False,), 2, 1, True),  # a quiet host: run once
        ((True, True, False), 2, 3, True),  # busy twice, quiet the third time
        ((True, True, True), 1, 2, True),  # busy throughout: bounded, the last run is kept
        # a confirmation run of what the component holds only: judged on a busy host too
        ((True, True, True), 2, 1, False),
    ],
)
def test_an_execution_the_host_was_busy_in_is_run_again_boundedly_and_says_so(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    busy: tuple[bool, ...],
    retries: int,
    runs: int,
    matters: bool,
) -> None:
    monkeypatch.delenv("REDLINE_DISTURBED_CPU_PERCENT", raising=False)
    repo, commit = committed_repo(tmp_path / "repo", SUITE_FILES)
    given: list[dict[str, str]] = []
    chosen: list[tuple[object, object, bool]] = []

    def run_isolated(
        suite_path: Path, out: Path, run_metadata: dict, only: object, sets: object, alone: bool
    ) -> RunResult:
        """The run, as the recorder writes it: the host at 90 % of 2 cores while the run's own
        processes used 24 % of one (156 % other load: busy), or at 20 % (16 %: quiet)."""
        given.append(dict(run_metadata))
        chosen.append((only, sets, alone))
        host = 90.0 if busy[len(given) - 1] else 20.0
        cpu = {"cpu_percent": np.full(50, 20.0)}
        write_recording(out, run_metadata, cpu, host_percent=host)
        return RunResult(out, None, 1, run_metadata, {})

    monkeypatch.setattr(daemon_module, "run_isolated", run_isolated)
    waits: list[tuple[float, float, int]] = []  # each retry first waits for a quiet host
    monkeypatch.setattr(
        daemon_module,
        "wait_for_quiet",
        lambda limit, most: waits.append((limit, most, len(given))) or 3.0,
    )
    daemon = AgentDaemon(
        client=_LostLeaseClient(),  # type: ignore[arg-type]
        workdir=tmp_path / "work",
        allow_file_repos=True,
        disturbed_retries=retries,
        quiet_wait=45.0,
    )
    # a confirmation run's job: its cases and parameter sets reach the run, each time
    sets = {"steady": ['{"rate":10}']}
    job = {**_LostLeaseClient().lease(), "repo": str(repo), "commit": commit}
    job.update(cases=["steady"], parameter_sets=sets, sets_alone=True, busy_matters=matters)
    out = daemon._run(job, "job-7")
    assert len(given) == runs
    assert waits == [(30.0, 45.0, run) for run in range(1, runs)]  # each busy run's but the last
    assert chosen == [(["steady"], sets, True)] * runs
    assert "disturbed_runs" not in given[0]
    for attempt, metadata in enumerate(given[1:], start=1):  # each retry says it is one
        assert metadata["disturbed_runs"] == str(attempt)
        assert metadata["disturbed_reason"].startswith("host busy: other load 156 % of a core")
    uploaded = read_recording(out).run
    assert uploaded.get("disturbed_runs") == (str(runs - 1) if runs > 1 else None)


class _FailingClient(_LostLeaseClient):
    """A server that keeps the lease and records what a failed job is failed with."""

    def __init__(self, repo: Path, commit: str) -> None:
        super().__init__()
        self.job = {**super().lease(), "repo": str(repo), "commit": commit}
        self.reasons: list[str] = []
        self.of_commit: list[bool] = []

    def lease(self, wait: int = 0) -> dict:
        return self.job

    def heartbeat(self, job_id: int) -> None:
        return None

    def fail(self, job_id: int, reason: str, of_commit: bool = False) -> None:
        self.reasons.append(reason)
        self.of_commit.append(of_commit)


def test_a_broken_suite_file_is_named_as_in_the_repository_not_where_the_host_checked_it_out(
    tmp_path: Path,
) -> None:
    """A trial's three executions failed with one error said with three paths of the agent's
    cache ('.../agent/cache/trees/job-13/perf/redline.toml:4:20')."""
    broken = {**SUITE_FILES, "perf/redline.toml": 'name = "s"\ntests = [\n'}
    repo, commit = committed_repo(tmp_path / "repo", broken)
    client = _FailingClient(repo, commit)
    daemon = AgentDaemon(
        client=client,  # type: ignore[arg-type]
        workdir=tmp_path / "work",
        allow_file_repos=True,
    )
    assert daemon.run_once() is True
    (reason,) = client.reasons
    assert reason.startswith("SuiteError: perf/redline.toml:"), reason
    assert str(tmp_path / "work") not in reason


@pytest.mark.parametrize(
    ("files", "run_fails", "of_commit"),
    [
        ({"perf/redline.toml": 'name = "s"\ntests = [\n'}, False, True),  # its suite file
        # its build (a top-level key, before the first table)
        (
            {"perf/redline.toml": 'build = "false"\n' + SUITE_FILES["perf/redline.toml"]},
            False,
            True,
        ),
        # a build the host lacks a tool for (the shell's 127): the host's fault, not the commit's
        (
            {"perf/redline.toml": 'build = "exit 127"\n' + SUITE_FILES["perf/redline.toml"]},
            False,
            False,
        ),
        ({}, True, False),  # a run that failed: it may not fail alike the next time
    ],
)
def test_a_fault_of_the_commit_itself_is_told_as_such_and_a_failed_run_is_not(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    files: dict[str, str],
    run_fails: bool,
    of_commit: bool,
) -> None:
    """A trial's broken suite failed its three executions one after another (41 s), each with
    the same words: a fault of the commit (its suite file, its build) is told as such, so that
    the server runs none of the others; a run that failed is not."""
    from redline.agent.isolated import ChildFailed

    trace = 'Traceback (most recent call last):\n  File "perf/test_s.py", line 2, in run\n'

    def run_isolated(*args: object) -> RunResult:
        raise ChildFailed("RuntimeError: boom (raised at test_s.py:2, in run)", trace)

    if run_fails:
        monkeypatch.setattr(daemon_module, "run_isolated", run_isolated)
    repo, commit = committed_repo(tmp_path / "repo", {**SUITE_FILES, **files})
    client = _FailingClient(repo, commit)
    daemon = AgentDaemon(client=client, workdir=tmp_path / "work", allow_file_repos=True)  # type: ignore[arg-type]
    assert daemon.run_once() is True
    assert client.of_commit == [of_commit], client.reasons
    if run_fails:  # the reason in a line, the whole traceback in the agent's log
        assert client.reasons == ["RuntimeError: boom (raised at test_s.py:2, in run)"]
        assert trace.rstrip() in caplog.text
    if files.get("perf/redline.toml", "").startswith('build = "false"'):
        said = "build command 'sh -c false' exited with 1, printing nothing"
        assert client.reasons == [said], client.reasons


def test_a_run_records_the_hash_it_checked_out_whatever_name_it_was_given(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A job may name its commit by a branch (an admin's revision), which moves: the recording
    says which commit was measured, by its hash, beside the name it was leased
    (`redline.server.services.measured_commit` pins it)."""
    repo, head = committed_repo(tmp_path / "repo", SUITE_FILES)

    def run_isolated(suite_path: Path, out: Path, run_metadata: dict, *rest: object) -> RunResult:
        write_recording(out, run_metadata, {"cpu_percent": np.full(50, 20.0)}, host_percent=20.0)
        return RunResult(out, None, 1, run_metadata, {})

    monkeypatch.setattr(daemon_module, "run_isolated", run_isolated)
    daemon = AgentDaemon(
        client=_LostLeaseClient(),  # type: ignore[arg-type]
        workdir=tmp_path / "work",
        allow_file_repos=True,
    )
    for name in ("main", head[:9]):
        job = {**_LostLeaseClient().lease(), "repo": str(repo), "commit": name}
        run = read_recording(daemon._run(job, f"job-{name}")).run
        assert (run["commit"], run["commit_sha"]) == (name, head)
