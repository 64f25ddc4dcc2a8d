"""Running a suite once: environment, processes, test execution, one MCAP recording.

`run_suite` loads the suite and its tests, validates the parameters, then in a temporary workspace
(every process's log in it): opens the run's isolated zenoh network, starts the recorder and waits
until it is subscribed, starts fixtures and components with ``ZENOH_CONFIG`` and waits for their
readiness, starts the monitor on the components' PIDs, runs every case → phase → parameter set
between markers, and stops everything in reverse order; the recorder finishes the file last, so
the recording keeps what was captured even when the run fails.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import zenoh
from redline.agent.execution import Markers, execute_cases
from redline.agent.governor import pinned_governor
from redline.agent.host import host_fingerprint
from redline.agent.loader import load_test_cases
from redline.agent.network import RunNetwork, open_client
from redline.agent.processes import ManagedProcess, RunError
from redline.agent.recorder import STATUS_KEY
from redline.agent.selection import select_cases
from redline.agent.suite import ProcessSpec, ReadyCheck, Suite, load_suite
from redline.testing import Link, Stop, TestCase, validate_cases

Progress = Callable[[str], None]


@dataclass(frozen=True)
class RunResult:
    """What a finished run produced."""

    recording: Path
    workspace: Path | None  # kept only on failure or when asked
    segments: int
    run_metadata: dict[str, str]
    host: dict[str, str]


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "unknown"


def query_recorder(session: zenoh.Session, timeout: float = 1.0) -> dict[str, int] | None:
    """The recorder's counts, or None when it does not answer (yet)."""
    for reply in session.get(STATUS_KEY, timeout=timeout):
        if reply.ok is not None:
            return dict(json.loads(reply.ok.payload.to_bytes()))
    return None


class _Run:
    """One execution of a suite in a workspace; `execute` does it and cleans up after itself."""

    def __init__(
        self,
        suite: Suite,
        cases: list[TestCase],
        workspace: Path,
        out: Path,
        run_metadata: dict[str, str],
        say: Progress,
    ) -> None:
        self.suite, self.cases, self.workspace, self.out = suite, cases, workspace, out
        self.say = say
        self.meta_path = workspace / "run-meta.json"
        self.meta: dict[str, dict[str, str]] = {"run": self._run_metadata(run_metadata), "host": {}}
        self.started: list[ManagedProcess] = []
        self.stop = Stop()
        self.segments = 0

    def _run_metadata(self, given: dict[str, str]) -> dict[str, str]:
        names = [spec.name for spec in self.suite.components]
        return {
            "component": names[0],
            **given,
            "suite": self.suite.name,
            "suite_file": str(self.suite.path),
            "suite_sha256": self.suite.sha256,
            "components": ",".join(names),
            "sampling_hz": f"{self.suite.sampling_hz:g}",
            "redline_version": _version("redline-agent"),
            "zenoh_version": _version("eclipse-zenoh"),
            "started_at": _now(),
            "ended_at": "",
            "status": "running",
        }

    def _write_meta(self) -> None:
        self.meta_path.write_text(json.dumps(self.meta, indent=2))

    def _helper(
        self, name: str, args: list[str], env: dict[str, str], stop_timeout: float = 5.0
    ) -> ManagedProcess:
        spec = ProcessSpec(
            name=name,
            command=(sys.executable, "-m", *args),
            cwd=self.workspace,
            ready=ReadyCheck("log", f"^{name} ready"),
            start_timeout=30.0,
            stop_timeout=stop_timeout,
        )
        return self._start(spec, env)

    def _start(self, spec: ProcessSpec, env: dict[str, str]) -> ManagedProcess:
        process = ManagedProcess(spec, self.workspace, env).start()
        self.started.append(process)
        return process

    def execute(self) -> int:
        with pinned_governor() as governor, RunNetwork(transport=self.suite.transport) as network:
            self.meta["host"] = host_fingerprint(governor)
            self.say(f"governor: {governor}; zenoh router on {network.endpoint}")
            self._write_meta()
            helper_env = {"REDLINE_ZENOH": json.dumps(network.client_settings())}
            session: zenoh.Session | None = None
            try:
                recorder = self._helper(
                    "redline-recorder",
                    [
                        "redline.agent.recorder",
                        "--out",
                        str(self.out),
                        "--meta",
                        str(self.meta_path),
                    ],
                    helper_env,
                    60.0,
                )
                recorder.wait_ready()
                session = open_client(network.client_settings())
                recorder.wait_ready(probe=lambda: query_recorder(session, 0.5) is not None)
                self.say("recorder subscribed")
                self._run_tests(network, session, helper_env)
                self.meta["run"]["status"] = "ok"
            except BaseException as exc:
                self.meta["run"]["status"] = "failed"
                self.meta["run"]["error"] = f"{type(exc).__name__}: {exc}"[:4000]
                raise
            finally:
                self._shut_down(session)
        return self.segments

    def _run_tests(
        self, network: RunNetwork, session: zenoh.Session, helper_env: dict[str, str]
    ) -> None:
        config = {
            "ZENOH_CONFIG": str(
                network.write_component_config(self.workspace / "zenoh-component.json")
            )
        }
        components = [
            self._start_ready(spec, config, session)
            for spec in (*self.suite.fixtures, *self.suite.components)
        ]
        components = components[len(self.suite.fixtures) :]
        targets = [f"{p.name}={p.pid}" for p in components]
        monitor = self._helper(
            "redline-monitor",
            ["redline.agent.monitor", "--rate", f"{self.suite.sampling_hz:g}", *targets],
            helper_env,
        )
        monitor.wait_ready()
        watchdog = threading.Thread(target=self._watch, args=([*components, monitor],), daemon=True)
        watchdog.start()
        link, markers = Link(session), Markers(session)
        try:
            self.segments = execute_cases(self.cases, link, markers, self.stop, self.say)
        finally:
            self.stop.set()
            markers.close()
            link.close()
        for process in [*components, monitor]:
            process.check_alive()

    def _start_ready(
        self, spec: ProcessSpec, env: dict[str, str], session: zenoh.Session
    ) -> ManagedProcess:
        self.say(f"starting {spec.name}: {' '.join(spec.command)}")
        began = time.monotonic()
        process = self._start(spec, env)
        if spec.ready is not None and spec.ready.kind in ("key", "liveliness"):
            seen = threading.Event()
            subscriber = (
                session.declare_subscriber(str(spec.ready.value), lambda _s: seen.set())
                if spec.ready.kind == "key"
                else session.liveliness().declare_subscriber(
                    str(spec.ready.value), lambda _s: seen.set(), history=True
                )
            )
            try:
                process.wait_ready(probe=seen.is_set)
            finally:
                subscriber.undeclare()
        else:
            process.wait_ready()
        self.say(f"{spec.name} ready after {time.monotonic() - began:.1f} s (pid {process.pid})")
        return process

    def _watch(self, processes: list[ManagedProcess]) -> None:
        """Stop the tests as soon as a component or the monitor exits."""
        while not self.stop.wait(0.1):
            if any(p.exit_code() is not None for p in processes):
                self.stop.set()

    def _shut_down(self, session: zenoh.Session | None) -> None:
        self.stop.set()
        if not self.started:
            return  # the recorder itself could not start
        recorder, others = self.started[0], self.started[1:]
        for process in others:
            if process.name == "redline-monitor":
                process.stop()
        if session is not None:
            query_recorder(session, 5.0)  # barrier: what was published before has arrived
        for process in reversed(others):
            process.stop()
        if session is not None:
            session.close()
        self.meta["run"]["ended_at"] = _now()
        self._write_meta()
        code = recorder.stop()
        if code != 0 and sys.exc_info()[0] is None:
            raise RunError(
                f"the recorder failed (exit code {code}); log {recorder.log_path}:\n"
                f"{recorder.tail()}"
            )


def run_suite(
    suite_path: Path,
    out: Path,
    *,
    run_metadata: dict[str, str] | None = None,
    progress: Progress | None = None,
    keep_workspace: bool = False,
    only: Sequence[str] = (),
    overrides: Mapping[str, Any] | None = None,
) -> RunResult:
    """Run a suite once (one execution) and write its recording to ``out``.

    ``only`` restricts the run to the named test cases; ``overrides`` replaces parameter values
    in every parameter set (``{"rate": 40}``). Raises `SuiteError` for a bad suite file,
    `ValidationError` for tests that cannot run, and `RunError` (e.g. `ProcessExited`, with exit
    code and log tail) when the run fails; the workspace with every log is then kept and named
    in the progress output.
    """
    say = progress or (lambda _message: None)
    suite = load_suite(suite_path)
    cases = load_test_cases(suite.tests)
    validate_cases(cases)
    cases = select_cases(cases, only, overrides)
    validate_cases(cases)
    out = Path(out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    workspace = Path(tempfile.mkdtemp(prefix=f"redline-{suite.name}-"))
    say(f"suite {suite.name}: {len(cases)} test case(s); workspace {workspace}")
    run = _Run(suite, cases, workspace, out, dict(run_metadata or {}), say)
    kept = True
    try:
        segments = run.execute()
        kept = keep_workspace
    finally:
        if kept:
            say(f"workspace kept: {workspace}")
        else:
            shutil.rmtree(workspace, ignore_errors=True)
    say(f"recorded {segments} segment(s) to {out}")
    return RunResult(
        recording=out,
        workspace=workspace if kept else None,
        segments=segments,
        run_metadata=run.meta["run"],
        host=run.meta["host"],
    )


def execution_paths(out: Path, executions: int) -> list[Path]:
    """Where each execution's recording goes: ``out`` itself for one, else ``out-1.mcap``..."""
    out = Path(out)
    if executions == 1:
        return [out]
    return [out.with_name(f"{out.stem}-{index}{out.suffix}") for index in range(1, executions + 1)]


def run_executions(
    suite_path: Path,
    out: Path,
    *,
    executions: int | None = None,
    run_metadata: dict[str, str] | None = None,
    progress: Progress | None = None,
    **options: Any,
) -> list[RunResult]:
    """Run the suite ``executions`` times (default: the suite file's), one recording each.

    The components are started afresh for every execution (and never between parameter sets
    within one). ``options`` are those of `run_suite`.
    """
    say = progress or (lambda _message: None)
    count = executions if executions is not None else load_suite(suite_path).executions
    if count < 1:
        raise RunError(f"executions must be at least 1, got {count}")
    results = []
    for index, path in enumerate(execution_paths(out, count), start=1):
        if count > 1:
            say(f"execution {index} of {count} → {path}")
        meta = {**(run_metadata or {}), "execution": str(index), "executions": str(count)}
        results.append(run_suite(suite_path, path, run_metadata=meta, progress=progress, **options))
    return results
