"""`redline agent`: the performance-host daemon.

It registers, then loops: lease a job (a long poll), check out the revision, build it, run its
suite while heartbeating, upload the recording, and go back for the next job. Agents pull; the
server never reaches into a performance host. A recording the server cannot take now waits in the
spool (redline.agent.spool) and is sent in the background. On SIGTERM the agent finishes its job
and stops; a second signal (or the end of the grace period) releases the job instead.
"""

from __future__ import annotations

import logging
import subprocess
import threading
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
from redline.agent.checkout import CloneCache
from redline.agent.client import LeaseLost, ServerClient, ServerUnavailable, UploadRejected
from redline.agent.governor import governor_files
from redline.agent.host import host_fingerprint
from redline.agent.isolated import ChildFailed, adopt_orphans, run_isolated
from redline.agent.quiet import QUIET_WAIT_S, measuring, wait_for_quiet
from redline.agent.spool import Spool, SpoolSender
from redline.agent.suite import SuiteError, load_suite
from redline.recording import read_recording
from redline.recording.disturbance import recording_disturbances, threshold
from redline.recording.format import NO_TRAFFIC

log = logging.getLogger("redline.agent")

BUILD_TIMEOUT_S = 1800
MAX_RETRY_S = 10.0


class JobFailed(RuntimeError):
    """A job could not be completed; the message is the reason the server records.
    ``of_commit``: the commit's own fault (its suite file or build), which every execution of
    it meets alike: the server then runs none of its others (a trial's broken suite failed
    three executions one after another, 41 s, each with the same words)."""

    def __init__(self, reason: str, of_commit: bool = False) -> None:
        super().__init__(reason)
        self.of_commit = of_commit


class AgentStopping(BaseException):
    """Raised in the main thread by a second SIGTERM (or when the grace period ends).

    A BaseException, so that nothing catching ``Exception`` turns it into a failed job: the job
    in progress is released instead, back to the queue without counting an attempt.
    """


@dataclass
class AgentDaemon:
    client: ServerClient
    workdir: Path
    labels: list[str] = field(default_factory=list)
    poll_interval: float = 2.0
    long_poll: int = 20
    heartbeat_interval: float = 10.0
    #: may a job's repository be a local path or file:// URL (`redline up` on one machine)
    allow_file_repos: bool = False
    #: how many times an execution is run again when the host was busy during a phase
    disturbed_retries: int = 2
    #: ... each once the host is quiet, waited for at most this long (`wait_for_quiet`)
    quiet_wait: float = QUIET_WAIT_S
    stop: threading.Event = field(default_factory=threading.Event)
    #: the job being checked out, built or run: what a second signal releases
    current_job: int | None = None
    #: in the lease call: a stop signal may interrupt it at once
    waiting: bool = False

    def __post_init__(self) -> None:
        self.cache = CloneCache(self.workdir / "cache", allow_file=self.allow_file_repos)
        (self.workdir / "recordings").mkdir(parents=True, exist_ok=True)
        self.spool = Spool(self.workdir / "spool")
        self.sender = SpoolSender(self.spool, self.client, self.stop)

    def run_forever(self) -> None:
        if not adopt_orphans():
            log.warning("cannot adopt orphans here: a run killed outright may leave processes")
        self._register()
        self.sender.start()
        log.info("agent %s registered; waiting for jobs", self.client.host)
        delay = self.poll_interval
        while not self.stop.is_set():
            try:
                worked = self.run_once()
                delay = self.poll_interval
            except Exception:  # the server may be down: keep polling, never die
                log.exception("agent loop error; retrying in %.0fs", delay)
                self.stop.wait(delay)
                delay = min(delay * 2, MAX_RETRY_S)
                continue
            if not worked and not self.long_poll:
                self.stop.wait(self.poll_interval)

    def _register(self) -> None:
        governor = "available" if governor_files() else "unavailable"
        delay = self.poll_interval
        while True:
            try:
                self.client.register(host_fingerprint(governor), self.labels)
                return
            except httpx.HTTPError as exc:  # the server may be starting or its database away
                log.warning("cannot register yet (%s); retrying in %.0fs", exc, delay)
            if self.stop.wait(delay):
                raise AgentStopping("stopped before registering")
            delay = min(delay * 2, MAX_RETRY_S)

    def run_once(self) -> bool:
        """Lease and process one job; False when none was queued."""
        self.waiting = True
        try:
            job = self.client.lease(wait=self.long_poll)
        finally:
            self.waiting = False
        if self.spool.pending():  # the server answers again: no need to wait for the backoff
            self.sender.wake.set()
        if job is None:
            return False
        if self.stop.is_set():  # asked to stop while the lease was on its way
            self.client.release(job["id"])
            return False
        if self.spool.holds(job["id"]):  # run before, its lease lapsed while the server was away
            log.info(
                "job %s: its recording is spooled; sending it instead of running again", job["id"]
            )
            self.sender.send_all()
            return True
        log.info(
            "job %s: %s %s (%s)",
            job["id"],
            job["component"],
            job["revision"]["title"],
            job["commit"][:12],
        )
        try:
            execution = self._process(job)
            if execution is not None:
                log.info("job %s: uploaded as execution %s", job["id"], execution)
        except (JobFailed, UploadRejected) as exc:
            log.error("job %s failed: %s", job["id"], exc)
            of_commit = getattr(exc, "of_commit", False)
            self.client.fail(job["id"], self._in_repository(str(exc), job), of_commit)
        except LeaseLost as exc:
            log.warning("job %s: lease lost, abandoning it (%s)", job["id"], exc)
        except AgentStopping:
            log.warning("job %s: stopping before it finished; releasing it", job["id"])
            self.client.release(job["id"])
            raise
        return True

    def _in_repository(self, reason: str, job: dict[str, Any]) -> str:
        """``reason`` with the job's work tree left out of its paths: a repository's file is
        named as in the repository ("perf/redline.toml:4:20"), not where this host checked it
        out (a trial's three executions failed with three paths of one error)."""
        tree = self.cache.tree(f"job-{job['id']}")
        for path in dict.fromkeys((str(tree.resolve()), str(tree))):
            reason = reason.replace(f"{path}/", "")
        return reason

    def _process(self, job: dict[str, Any]) -> int | None:
        name = f"job-{job['id']}"
        self.current_job = job["id"]
        beats = _Heartbeat(self.client, job["id"], _beat_interval(job, self.heartbeat_interval))
        try:
            beats.start()
            out = self._run(job, name)
            self.current_job = None  # from here on the recording is kept, never released
            beats.check()
            return self._deliver(job["id"], out)
        except (LeaseLost, AgentStopping):
            raise
        except (JobFailed, UploadRejected):
            beats.check()  # a lost lease is not this host's to fail: another may run the job
            raise
        except Exception as exc:
            beats.check()
            raise JobFailed(f"{type(exc).__name__}: {exc}") from exc
        finally:
            self.current_job = None
            beats.stop()
            self.cache.discard(name)

    def _run(self, job: dict[str, Any], name: str) -> Path:
        """Check out, build and run the job's suite; the finished recording."""
        tree = self.cache.checkout(job["repo"], job["commit"], name)
        measured = {"commit_sha": self.cache.head(tree)}  # a branch's name moves; its hash not
        suite_path = (tree / job["suite"]).resolve()
        if not suite_path.is_relative_to(tree.resolve()):
            raise JobFailed(f"suite file {job['suite']} is outside the repository", True)
        if not suite_path.is_file():
            raise JobFailed(f"suite file {job['suite']} not found at commit {job['commit']}", True)
        try:
            suite = load_suite(suite_path)
        except SuiteError as exc:  # the suite file as this commit has it: each execution alike
            raise JobFailed(f"{type(exc).__name__}: {exc}", True) from exc
        _build(suite.build, suite.directory)
        out = self.workdir / "recordings" / f"{name}.mcap"
        retried: dict[str, str] = {}
        # a confirmation run of what the component holds only is judged on a busy host too
        retries = self.disturbed_retries if job.get("busy_matters", True) else 0
        for attempt in range(retries + 1):
            with measuring():  # on a shared machine, the worker's analysis waits meanwhile
                try:  # in a process of its own, which takes what the run left with it
                    result = run_isolated(
                        suite_path,
                        out,
                        {**_run_metadata(job), **measured, **retried},
                        job.get("cases") or (),
                        job.get("parameter_sets") or {},  # a confirmation run: its flagged sets
                        bool(job.get("sets_alone")),  # ... run alone (older servers: as far as)
                    )
                except ChildFailed as exc:  # the reason in a line; where, in the log
                    if exc.trace:
                        log.error("job %s: the run raised:\n%s", job["id"], exc.trace.rstrip())
                    raise JobFailed(str(exc)) from None
            busy = recording_disturbances(
                read_recording(out, strict=False).series_samples(), threshold()
            )
            if not busy or attempt == retries:
                break
            reason = next(iter(busy.values()))
            log.warning(
                "job %s: %s in %d phase(s); running the execution again (%d of %d) once the "
                "host is quiet",
                job["id"],
                reason,
                len(busy),
                attempt + 1,
                retries,
            )
            if wait_for_quiet(threshold(), self.quiet_wait) is None:
                log.warning(
                    "job %s: the host stayed busy for %.0f s; running it now",
                    job["id"],
                    self.quiet_wait,
                )
            # the retry is visible: the recording uploaded says how many runs were disturbed
            retried = {"disturbed_runs": str(attempt + 1), "disturbed_reason": reason}
        if result.run_metadata.get("status") == NO_TRAFFIC:  # uploaded: the server says why
            log.warning("job %s: no traffic: %s", job["id"], result.run_metadata.get("warning"))
        return out

    def _deliver(self, job_id: int, recording: Path) -> int | None:
        """Spool the recording, then upload it; left to the background sender if that fails."""
        entry = self.spool.put(job_id, recording)
        try:
            return self.spool.send(self.client, entry, attempts=3)
        except ServerUnavailable as exc:
            log.warning("job %s: server unavailable, recording spooled (%s)", job_id, exc)
            self.sender.wake.set()
            return None


def _beat_interval(job: dict[str, Any], most: float) -> float:
    """A third of the lease the server granted (so two beats may fail), at most ``most``."""
    try:
        expires = datetime.fromisoformat(job["lease_expires_at"])
        lease = (expires - datetime.now(UTC)).total_seconds()
    except (KeyError, TypeError, ValueError):
        return most
    return max(0.5, min(most, lease / 3))


def _run_metadata(job: dict[str, Any]) -> dict[str, str]:
    return {
        "job_id": str(job["id"]),
        "component": job["component"],
        "revision_title": job["revision"]["title"],
        "revision_sort_key": str(job["revision"]["sort_key"]),
        "commit": job["commit"],
        "execution_index": str(job["execution_index"]),
    }


def _build(command: tuple[str, ...] | None, cwd: Path) -> None:
    if not command:
        return
    shown = " ".join(command)
    log.info("building: %s", shown)
    try:
        done = subprocess.run(
            command, cwd=cwd, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise JobFailed(f"build command {shown!r} could not run: {exc}") from exc
    if done.returncode != 0:
        tail = (done.stdout + done.stderr).strip()[-2000:]
        said = f":\n{tail}" if tail else ", printing nothing"
        # the commit's own fault, unless the shell found no such command (126, 127: the host
        # lacks a tool) or a signal ended it (the host's memory, a timeout): those are the host's
        of_commit = 0 < done.returncode < 126
        raise JobFailed(f"build command {shown!r} exited with {done.returncode}{said}", of_commit)


class _Heartbeat:
    """Extends the job's lease in the background; remembers if the lease was lost."""

    def __init__(self, client: ServerClient, job_id: int, interval: float) -> None:
        self._client, self._job_id, self._interval = client, job_id, interval
        self._stop = threading.Event()
        self._lost: LeaseLost | None = None
        self._thread = threading.Thread(target=self._loop, name=f"heartbeat-{job_id}", daemon=True)

    def start(self) -> None:
        self._beat()
        self._thread.start()

    def _beat(self) -> None:
        try:
            self._client.heartbeat(self._job_id)
        except LeaseLost as exc:
            self._lost = exc
            self._stop.set()
        except Exception:  # a missed beat is not fatal: the lease outlives several intervals
            log.warning("heartbeat for job %s failed", self._job_id, exc_info=True)

    def _loop(self) -> None:
        while not self._stop.wait(self._interval):
            self._beat()

    def check(self) -> None:
        if self._lost is not None:
            raise self._lost

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
