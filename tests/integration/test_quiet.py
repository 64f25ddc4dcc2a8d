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
