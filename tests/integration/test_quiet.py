"""The measurement lock: on a shared machine, analysis never overlaps a run.

Serial: the lock's holders are child processes whose timing other tests' load would stretch.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from redline.agent import quiet

pytestmark = pytest.mark.serial

HOLDER = """
import sys, time
from pathlib import Path
from redline.agent.quiet import {kind}
log, go = Path(sys.argv[1]), Path(sys.argv[1] + ".go")
with {kind}():
    log.write_text("held\\n")
    deadline = time.monotonic() + {hold}  # hold until told to go, or for {hold} s
    while not go.exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    log.write_text("held\\nreleased\\n")
"""


def _hold_in_child(kind: str, log: Path, lock: Path, hold: float = 0.5) -> subprocess.Popen[bytes]:
    child = subprocess.Popen(
        [sys.executable, "-c", HOLDER.format(kind=kind, hold=hold), str(log)],
        env={**os.environ, quiet.LOCK_VARIABLE: str(lock)},
    )
    deadline = time.monotonic() + 20
    while "held" not in (log.read_text() if log.exists() else ""):
        assert time.monotonic() < deadline and child.poll() is None, "child never took the lock"
        time.sleep(0.01)
    return child


def test_analysis_waits_for_a_run_in_progress(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    lock, log = tmp_path / "measurement.lock", tmp_path / "log"
    monkeypatch.setenv(quiet.LOCK_VARIABLE, str(lock))
    child = _hold_in_child("measuring", log, lock)
    with quiet.analysing():
        assert "released" in log.read_text()
    assert child.wait(timeout=20) == 0


def test_a_run_waits_for_the_analysis_in_progress(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    lock, log = tmp_path / "measurement.lock", tmp_path / "log"
    monkeypatch.setenv(quiet.LOCK_VARIABLE, str(lock))
    child = _hold_in_child("analysing", log, lock)
    with quiet.measuring():
        assert "released" in log.read_text()
    assert child.wait(timeout=20) == 0


def test_analyses_share_the_lock_and_without_it_nothing_waits(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    lock, log = tmp_path / "measurement.lock", tmp_path / "log"
    monkeypatch.setenv(quiet.LOCK_VARIABLE, str(lock))
    child = _hold_in_child("analysing", log, lock, hold=60)  # until we say go
    with quiet.analysing():
        assert "released" not in log.read_text()  # two tasks at once: no waiting
    Path(f"{log}.go").touch()
    assert child.wait(timeout=20) == 0
    monkeypatch.delenv(quiet.LOCK_VARIABLE)
    with quiet.measuring(), quiet.measuring():  # no lock configured: a no-op, even nested
        pass


def test_a_run_again_after_a_busy_host_waits_until_the_host_is_quiet():
    """A trial's first demo ran its first two jobs three times each, one straight after the
    other, while something used 94-96 % of a core for about 45 s: none could be judged. A run
    again waits, up to a bound, until the host's load stays under the disturbance threshold; here
    a process spinning a core for 4 s is waited out, and one spinning throughout is not."""
    spin = "import time\nend = time.monotonic() + {s}\nwhile time.monotonic() < end: pass"
    spinner = subprocess.Popen([sys.executable, "-c", spin.format(s=4)])
    try:
        time.sleep(0.5)  # spinning
        began = time.monotonic()
        waited = quiet.wait_for_quiet(30.0, most_s=60)
        took = time.monotonic() - began
    finally:
        spinner.wait(timeout=30)
    # the spin's last 3.5 s or so were busy, then 3 quiet seconds in a row
    assert waited is not None and waited >= quiet.QUIET_SAMPLES + 2, (waited, took)
    spinner = subprocess.Popen([sys.executable, "-c", spin.format(s=8)])
    try:
        time.sleep(0.5)
        assert quiet.wait_for_quiet(30.0, most_s=4) is None  # busy throughout: given up
    finally:
        spinner.kill()
        spinner.wait(timeout=30)
