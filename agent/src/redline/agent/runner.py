"""Running a suite once: environment, processes, test execution, one MCAP recording.

`run_suite` loads the suite and its tests, validates the parameters, then in a workspace (every
process's log beside the recording; see `redline.agent.workspace`): opens the run's isolated zenoh
network, starts the recorder and waits
until it is subscribed, starts fixtures and components with ``ZENOH_CONFIG`` and waits for their
readiness, starts the monitor on the components' PIDs, runs every case → phase → parameter set
between markers, and stops everything in reverse order; the recorder finishes the file last, so
the recording keeps what was captured even when the run fails.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import zenoh
from redline.agent.affinity import AffinityError, check_available, pinned
from redline.agent.execution import Markers, execute_cases
from redline.agent.governor import pinned_governor
from redline.agent.host import host_fingerprint
from redline.agent.interrupts import SignalGuard, ending, signals_as_exceptions
from redline.agent.loader import load_test_cases
from redline.agent.network import RunNetwork, open_client, session_id
from redline.agent.processes import ManagedProcess, RunError
from redline.agent.recorder import query_recorder, recorded_traffic
from redline.agent.selection import choose_sets, select_cases
from redline.agent.suite import ProcessSpec, ReadyCheck, Suite, load_suite
from redline.agent.traffic import NetworkView, TrafficCheck
from redline.agent.workspace import fresh_logs, new_workspace, tidy
from redline.recording.format import NO_TRAFFIC, REDLINE_PREFIX
from redline.testing import Link, Stop, TestCase, validate_cases

Progress = Callable[[str], None]


@dataclass(frozen=True)
class RunResult:
    """What a finished run produced."""

    recording: Path
    workspace: Path | None  # kept only when asked
    segments: int
    run_metadata: dict[str, str]
    host: dict[str, str]
    logs: Path | None = None  # the processes' logs beside the recording, kept when asked


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "unknown"


class _Run:
    """One execution of a suite in a workspace; `execute` does it and cleans up after itself."""

    def __init__(
        self,
        suite: Suite,
        cases: list[TestCase],
        places: tuple[Path, Path],
        out: Path,
        run_metadata: dict[str, str],
        say: Progress,
        guard: SignalGuard,
    ) -> None:
        self.suite, self.cases, self.out = suite, cases, out
        self.workspace, self.logs = places
        self.say, self.guard = say, guard
        self.meta_path = self.workspace / "run-meta.json"
        self.meta: dict[str, dict[str, str]] = {"run": self._run_metadata(run_metadata), "host": {}}
        self.started: list[ManagedProcess] = []
        self.stop = Stop()
        self.segments = 0
        self.traffic = TrafficCheck()
        self.driver_keys: frozenset[str] = frozenset()

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
        self, name: str, args: list[str], network: RunNetwork, stop_timeout: float = 5.0
    ) -> ManagedProcess:
        """A process of Redline's own (``redline-recorder``, ``redline-monitor``), on the cores
        the suite's affinity gives it, with a zenoh session id the traffic check knows."""
        zid = session_id()
        self.traffic.own_sessions.add(zid)
        spec = ProcessSpec(
            name=name,
            command=(sys.executable, "-m", *args),
            cwd=self.workspace,
            ready=ReadyCheck("log", f"^{name} ready"),
            start_timeout=30.0,
            stop_timeout=stop_timeout,
            cpus=self.suite.affinity.of(name.removeprefix("redline-")),
        )
        return self._start(spec, {"REDLINE_ZENOH": json.dumps(network.client_settings(zid))})

    def _start(self, spec: ProcessSpec, env: dict[str, str]) -> ManagedProcess:
        with self.guard.held():  # a process started is a process the shutdown knows of
            process = ManagedProcess(spec, self.logs, env).start()
            self.started.append(process)
        return process

    def execute(self) -> int:
        with ExitStack() as stack:
            with self.guard.held():
                governor = stack.enter_context(pinned_governor())
                # the driver and the router (their threads start inside) on the driver's cores
                stack.enter_context(pinned(self.suite.affinity.of("driver")))
                network = stack.enter_context(RunNetwork(transport=self.suite.transport))
            self.meta["host"] = host_fingerprint(governor)
            self.meta["run"]["affinity"] = self.suite.affinity.describe()
            self.say(
                f"governor: {governor}; zenoh router on {network.endpoint}; affinity: "
                f"{self.meta['run']['affinity']}"
            )
            self._write_meta()
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
                    network,
                    60.0,
                )
                recorder.wait_ready()
                driver = session_id()
                self.traffic.own_sessions.add(driver)
                session = open_client(network.client_settings(driver))
                recorder.wait_ready(probe=lambda: query_recorder(session, 0.5) is not None)
                self.say("recorder subscribed")
                self._run_tests(network, session)
                self.guard.raise_swallowed()
                self._judge_traffic(network, session)
            except BaseException as exc:
                self.meta["run"].update(ending(exc))
                raise
            finally:
                self.guard.stopping()  # a second signal must not cut the shutdown short
                self._shut_down(session)
        return self.segments

    def _judge_traffic(self, network: RunNetwork, session: zenoh.Session) -> None:
        """Every test ran: ``ok``, or ``no_traffic`` said loudly (`redline.agent.traffic`)."""
        own, recorded = self.traffic.own_sessions, recorded_traffic(session)
        seen: NetworkView | None = None
        if recorded is not None:  # else the last rule cannot be applied
            subscribed = network.subscriptions()
            seen = NetworkView(
                recorded=recorded,
                driver_keys=self.driver_keys,
                subscriptions=frozenset(key for key, zids in subscribed.items() if zids - own),
            )
        warnings = self.traffic.warnings(network.sessions_seen(), seen)
        if not warnings:
            self.meta["run"]["status"] = "ok"
            return
        self.meta["run"].update(status=NO_TRAFFIC, warning="; ".join(warnings))
        for warning in warnings:
            self.say(f"WARNING: no traffic: {warning}")

    def _run_tests(self, network: RunNetwork, session: zenoh.Session) -> None:
        path = str(network.write_component_config(self.workspace / "zenoh-component.json"))
        components = [
            self._start_ready(
                spec.expanded({"zenoh_config": path}), {"ZENOH_CONFIG": path}, session
            )
            for spec in (*self.suite.fixtures, *self.suite.components)
        ]
        components = components[len(self.suite.fixtures) :]
        targets = [f"{p.name}={p.pid}" for p in components]
        # Redline's own: this process (driver, router) and the recorder, started first
        own = [arg for pid in (os.getpid(), self.started[0].pid) for arg in ("--own", str(pid))]
        monitor = self._helper(
            "redline-monitor",
            ["redline.agent.monitor", "--rate", f"{self.suite.sampling_hz:g}", *own, *targets],
            network,
        )
        monitor.wait_ready()
        watchdog = threading.Thread(target=self._watch, args=([*components, monitor],), daemon=True)
        watchdog.start()
        link, markers = Link(session, self.guard.held), Markers(session, self.guard.held)
        try:
            self.segments = execute_cases(
                self.cases, link, markers, self.stop, self.say, self.traffic.observe
            )
        finally:
            self.stop.set()
            self.driver_keys = frozenset(
                key for key in link.published_keys() if not key.startswith(REDLINE_PREFIX)
            )
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
        # its output goes into the recording (the recorder attaches it as it finishes)
        self.meta.setdefault("logs", {})[spec.name] = str(process.log_path)
        self._write_meta()
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
    work_dir: str | Path | None = None,
    parameter_sets: Mapping[str, Collection[str]] | None = None,
    sets_alone: bool = False,
) -> RunResult:
    """Run a suite once (one execution) and write its recording to ``out``.

    ``only`` restricts the run to the named test cases, and ``parameter_sets`` ends it after
    the last of those sets (canonical JSON, `choose_sets`: a confirmation run's), or with
    ``sets_alone`` runs those sets only; ``overrides``
    replaces parameter values in every parameter set (``{"rate": 40}``). The workspace is made
    in ``work_dir`` (default: ``$REDLINE_WORK_DIR``, else the system's temporary folder) and
    removed afterwards unless ``keep_workspace``; every process logs to
    ``<out without suffix>.logs/``, kept when the run fails (or with ``keep_workspace``).
    Raises `SuiteError` for a bad suite file, `ValidationError` for tests that cannot run, and
    `RunError` (e.g. `ProcessExited`, with exit code, log path and log tail) when the run
    fails. Called from the main thread, SIGTERM and SIGHUP raise `Terminated` during the run as
    SIGINT raises `KeyboardInterrupt` (see `redline.agent.interrupts`): every process is
    stopped and the recording finished as ``terminated`` or ``interrupted`` first.
    """
    say = progress or (lambda _message: None)
    suite = load_suite(suite_path)
    try:  # before anything starts: a core this host does not offer is the suite's fault
        for cores in [
            *suite.affinity.cores.values(),
            *(spec.cpus for spec in (*suite.components, *suite.fixtures)),
        ]:
            check_available(cores)
    except AffinityError as exc:
        raise RunError(f"{suite.path}: {exc}") from None
    cases = load_test_cases(suite.tests)
    validate_cases(cases, files=False)  # the chosen cases' files, below
    cases = select_cases(cases, only, overrides)
    if parameter_sets:
        cases = choose_sets(cases, parameter_sets, sets_alone)
    validate_cases(cases)
    out = Path(out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    with signals_as_exceptions() as guard:
        with guard.held():  # a workspace made is a workspace removed
            places = new_workspace(suite.name, work_dir), fresh_logs(out)
        say(f"suite {suite.name}: {len(cases)} test case(s); workspace {places[0]}")
        run = _Run(suite, cases, places, out, dict(run_metadata or {}), say, guard)
        succeeded = False
        try:
            segments = run.execute()
            succeeded = True
        finally:
            workspace, logs = tidy(*places, succeeded=succeeded, keep=keep_workspace, say=say)
    say(f"recorded {segments} segment(s) to {out}")
    return RunResult(
        recording=out,
        workspace=workspace,
        segments=segments,
        run_metadata=run.meta["run"],
        host=run.meta["host"],
        logs=logs,
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
    with signals_as_exceptions():  # between executions too: a signal ends them all
        for index, path in enumerate(execution_paths(out, count), start=1):
            if count > 1:
                say(f"execution {index} of {count} → {path}")
            meta = {**(run_metadata or {}), "execution": str(index), "executions": str(count)}
            results.append(
                run_suite(suite_path, path, run_metadata=meta, progress=progress, **options)
            )
    return results
