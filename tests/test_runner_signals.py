"""However a run ends (SIGTERM, SIGHUP, SIGINT), every process of it stops and its recording is
finished with the true status: from `redline run` and from a script calling `run_suite`.

Each run is a real subprocess on the echo example. Its environment carries a marker that every
process it starts inherits, so the processes of the run are found in /proc whatever they are.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from redline.agent.interrupts import Terminated, signals_as_exceptions
from redline.recording import read_recording

ROOT = Path(__file__).resolve().parents[1]
ECHO = ROOT / "examples" / "echo" / "perf" / "redline.toml"
MARK = "REDLINE_TEST_RUN_MARK"
FIRST_MEASURED = "ping/steady [rate=50,size=64]"  # more segments follow it: the run goes on

pytestmark = pytest.mark.integration


def _marked(mark: str) -> list[int]:
    """PIDs of the live processes whose environment carries the marker."""
    needle = f"{MARK}={mark}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        with contextlib.suppress(OSError):  # gone meanwhile, or not ours to read
            if needle in (entry / "environ").read_bytes().split(b"\0"):
                found.append(int(entry.name))
    return found


def _none_left(mark: str, within: float = 5.0) -> list[int]:
    """The marked processes still alive after ``within`` seconds (none, for a clean stop)."""
    deadline = time.monotonic() + within
    while (left := _marked(mark)) and time.monotonic() < deadline:
        time.sleep(0.1)
    return left


@pytest.fixture
def mark() -> Iterator[str]:
    """A fresh marker; whatever still carries it at the end is killed (a failed test leaks
    nothing into the other tests)."""
    value = uuid.uuid4().hex
    yield value
    for pid in _marked(value):
        with contextlib.suppress(OSError):
            os.killpg(pid, signal.SIGKILL)


def _start(argv: list[str], mark: str, cwd: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "COLUMNS": "200", MARK: mark, "REDLINE_WORK_DIR": str(cwd)}
    return subprocess.Popen(
        argv, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )


def _wait_until_measuring(run: subprocess.Popen[str]) -> list[str]:
    """Read the run's output until the first measured segment has begun."""
    assert run.stdout is not None
    seen = []
    for line in run.stdout:
        seen.append(line)
        if FIRST_MEASURED in line:
            return seen
    raise AssertionError(f"the run ended before measuring (exit {run.wait()}):\n{''.join(seen)}")


def _stopped_by(run: subprocess.Popen[str], signum: int) -> tuple[int, str]:
    _wait_until_measuring(run)
    run.send_signal(signum)
    assert run.stdout is not None
    rest = run.stdout.read()
    return run.wait(60), rest


@pytest.mark.parametrize(
    ("signum", "status", "code"),
    [
        (signal.SIGTERM, "terminated", 143),
        (signal.SIGHUP, "terminated", 129),
        (signal.SIGINT, "interrupted", 130),
    ],
)
def test_a_signal_to_redline_run_stops_every_process_and_finishes_the_recording(
    tmp_path: Path, mark: str, signum: int, status: str, code: int
) -> None:
    out = tmp_path / "echo.mcap"
    redline = str(Path(sys.executable).parent / "redline")
    run = _start([redline, "run", str(ECHO), "--out", str(out)], mark, tmp_path)
    exit_code, rest = _stopped_by(run, signum)
    assert exit_code == code, rest
    assert _none_left(mark) == []
    name = signal.Signals(signum).name
    assert name in rest and "every process was stopped" in rest
    recording = read_recording(out)  # strict: a finished recording
    assert recording.run["status"] == status and recording.run["signal"] == name
    assert recording.run["ended_at"] > recording.run["started_at"]
    begins = [m for m in recording.markers if m["event"] == "begin"]
    assert begins and len(recording.segments()) == len(begins)  # every segment begun has ended
    assert not list(tmp_path.glob("redline-*")), "the workspace was left behind"


SCRIPT = """\
    import sys
    from pathlib import Path
    from redline.agent.runner import run_suite

    run_suite(Path(sys.argv[1]), Path(sys.argv[2]), progress=lambda m: print(m, flush=True))
    print("run_suite returned", flush=True)
    """


def test_sigterm_to_a_script_calling_run_suite_stops_the_run_and_raises(
    tmp_path: Path, mark: str
) -> None:
    script = tmp_path / "script.py"
    script.write_text(textwrap.dedent(SCRIPT))
    out = tmp_path / "api.mcap"
    run = _start([sys.executable, str(script), str(ECHO), str(out)], mark, tmp_path)
    exit_code, rest = _stopped_by(run, signal.SIGTERM)
    assert exit_code != 0 and "run_suite returned" not in rest
    assert "Terminated: terminated by SIGTERM" in rest
    assert _none_left(mark) == []
    recording = read_recording(out)
    assert recording.run["status"] == "terminated" and recording.run["signal"] == "SIGTERM"


def test_the_guard_raises_in_the_main_thread_and_restores_the_handlers() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Terminated) as caught, signals_as_exceptions():
        signal.raise_signal(signal.SIGTERM)  # delivered to this thread before it returns
        pytest.fail("the signal did not interrupt")
    assert caught.value.signal_name == "SIGTERM"
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_signal_in_a_held_section_is_raised_when_the_section_ends() -> None:
    finished = []
    with pytest.raises(Terminated), signals_as_exceptions() as guard:
        with guard.held():
            signal.raise_signal(signal.SIGHUP)
            finished.append("held section")
        finished.append("after it")
    assert finished == ["held section"]


def test_a_signal_while_stopping_is_raised_once_everything_is_stopped() -> None:
    finished = []
    with pytest.raises(KeyboardInterrupt), signals_as_exceptions() as guard:
        guard.stopping()
        signal.raise_signal(signal.SIGINT)
        finished.append("shut down")
    assert finished == ["shut down"]


def test_a_callers_own_handler_runs_but_never_inside_a_held_section() -> None:
    caught: list[int] = []

    def own(signum: int, _frame: object) -> None:
        caught.append(signum)

    previous = signal.signal(signal.SIGTERM, own)
    try:
        with signals_as_exceptions() as guard:
            signal.raise_signal(signal.SIGTERM)
            assert caught == [signal.SIGTERM]  # at once, and the run goes on
            with guard.held():
                signal.raise_signal(signal.SIGTERM)
                assert caught == [signal.SIGTERM]
            assert caught == [signal.SIGTERM] * 2
        assert signal.getsignal(signal.SIGTERM) is own
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_an_ignored_signal_stays_ignored() -> None:
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with signals_as_exceptions():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            signal.raise_signal(signal.SIGHUP)
    finally:
        signal.signal(signal.SIGHUP, previous)
