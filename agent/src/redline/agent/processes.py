"""Starting, watching and stopping the processes of a run, each with its log in the workspace."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO

from redline.agent.affinity import AffinityError, preexec
from redline.agent.suite import ProcessSpec

POLL_S = 0.05


class RunError(RuntimeError):
    """A run that could not complete; the message says what went wrong and where to look."""


class ProcessExited(RunError):
    """A process of the run exited when it should have kept running."""

    def __init__(self, name: str, code: int, log: Path, tail: str) -> None:
        self.name, self.code, self.log = name, code, log
        super().__init__(
            f"{name} exited early with exit code {code}; log {log}, last lines:\n{tail}"
        )


class ManagedProcess:
    """One process of a run: started in its own session, logged to ``<logs>/<name>.log``."""

    def __init__(self, spec: ProcessSpec, logs: Path, env: dict[str, str]) -> None:
        self.spec = spec
        self.log_path = logs / f"{spec.name}.log"
        self._env = {**os.environ, "PYTHONUNBUFFERED": "1", **spec.env, **env}
        self._popen: subprocess.Popen[bytes] | None = None
        self._log: IO[bytes] | None = None
        self._started = 0.0
        self._stopped = False

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def pid(self) -> int:
        assert self._popen is not None, "process not started"
        return self._popen.pid

    def start(self) -> ManagedProcess:
        try:
            pin = preexec(self.spec.cpus)
        except AffinityError as exc:
            raise RunError(f"cannot start {self.name}: {exc}") from None
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        try:
            self._popen = subprocess.Popen(
                self.spec.command,
                cwd=self.spec.cwd,
                env=self._env,
                stdin=subprocess.DEVNULL,
                stdout=self._log,
                stderr=subprocess.STDOUT,
                preexec_fn=pin,
                start_new_session=True,  # Ctrl-C reaches the runner only; it stops every process
            )
        except OSError as exc:
            raise RunError(
                f"cannot start {self.name} ({' '.join(self.spec.command)}) "
                f"in {self.spec.cwd}: {exc}"
            ) from None
        self._started = time.monotonic()
        return self

    def exit_code(self) -> int | None:
        return None if self._popen is None else self._popen.poll()

    def check_alive(self) -> None:
        """Raise `ProcessExited` (with exit code and log tail) if the process has ended."""
        code = self.exit_code()
        if code is not None:
            raise ProcessExited(self.name, code, self.log_path, self.tail())

    def tail(self, lines: int = 15) -> str:
        try:
            text = self.log_path.read_bytes()[-8192:].decode(errors="replace")
        except OSError:
            return "(no log)"
        return "\n".join(text.splitlines()[-lines:]) or "(empty log)"

    def _log_matches(self, pattern: re.Pattern[str]) -> bool:
        try:
            return pattern.search(self.log_path.read_bytes().decode(errors="replace")) is not None
        except OSError:
            return False

    def wait_ready(self, probe: Callable[[], bool] | None = None) -> None:
        """Wait for the readiness check (and ``probe``, if given) within the start timeout."""
        ready = self.spec.ready
        is_log = ready is not None and ready.kind == "log"
        pattern = re.compile(str(ready.value), re.MULTILINE) if ready and is_log else None
        deadline = self._started + self.spec.start_timeout
        while True:
            self.check_alive()
            elapsed = time.monotonic() - self._started
            passed = (
                (pattern is None or self._log_matches(pattern))
                and (ready is None or ready.kind != "delay" or elapsed >= float(ready.value))
                and (probe is None or probe())
            )
            if passed:
                return
            if time.monotonic() > deadline:
                raise RunError(
                    f"{self.name} was not ready within {self.spec.start_timeout:g} s "
                    f"({_describe(self.spec)}); log {self.log_path}, last lines:\n"
                    f"{self.tail()}"
                )
            time.sleep(POLL_S)

    def stop(self) -> int | None:
        """SIGTERM the process group, SIGKILL it after the stop timeout; returns the exit code."""
        if self._popen is None or self._stopped:
            return None if self._popen is None else self._popen.returncode
        self._stopped = True
        try:
            if self._popen.poll() is None:
                _signal_group(self._popen.pid, signal.SIGTERM)
                try:
                    self._popen.wait(self.spec.stop_timeout)
                except subprocess.TimeoutExpired:
                    _signal_group(self._popen.pid, signal.SIGKILL)
                    self._popen.wait()
            else:
                _signal_group(self._popen.pid, signal.SIGKILL)  # orphans left in its group
        finally:
            if self._log is not None:
                self._log.close()
        return self._popen.returncode


def _signal_group(pid: int, signum: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pid, signum)


def _describe(spec: ProcessSpec) -> str:
    if spec.ready is None:
        return "no readiness check"
    if spec.ready.kind == "log":
        return f"waiting for log line matching {spec.ready.value!r}"
    if spec.ready.kind == "liveliness":
        return f"waiting for a zenoh liveliness token on {spec.ready.value!r}"
    if spec.ready.kind == "key":
        return f"waiting for a sample on zenoh key {spec.ready.value!r}"
    return f"waiting {spec.ready.value} s"
