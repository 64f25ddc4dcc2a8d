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
from redline.recording import read_recording

from tests.support import ROOT

ECHO = ROOT / "examples" / "echo" / "perf" / "redline.toml"
MARK = "REDLINE_TEST_RUN_MARK"
FIRST_MEASURED = "ping/steady [rate=50,size=64]"  # more segments follow it: the run goes on


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
        argv,
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        # as from a terminal: a suite started under nohup inherits an ignored SIGHUP, which the
        # run rightly leaves ignored (redline.agent.interrupts), and its SIGHUP case would pass 0
        preexec_fn=_hangup_by_default,
    )


def _hangup_by_default() -> None:
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


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
