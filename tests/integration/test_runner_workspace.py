"""Where a run's files go: workspaces in the chosen work folder, removed after every run unless
kept; the logs of a failed run next to its recording, named in the error with their tail."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest
from redline.agent.processes import ProcessExited
from redline.agent.runner import run_suite

GIVES_UP = """\
    import sys, time
    print("component ready", flush=True)
    time.sleep(0.5)
    print("giving up", flush=True)
    sys.exit(3)
    """

ALIVE = """\
    import signal, threading, zenoh
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set).start())
    with zenoh.open(zenoh.Config.from_env()) as session:
        print("component ready", flush=True)
        while not stop.wait(0.1):
            session.put("demo/alive", b"1")
    """

TEST = """\
    from redline.testing import FixedRate, Phase, Publish, TestCase
    case = TestCase("c", [Phase("p", FixedRate(20, {seconds}, Publish("x/y", b"1")))])
    """


def _suite(folder: Path, component: str, seconds: float) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "component.py").write_text(textwrap.dedent(component))
    (folder / "test_it.py").write_text(textwrap.dedent(TEST).format(seconds=seconds))
    path = folder / "redline.toml"
    path.write_text(
        textwrap.dedent("""\
        name = "ws"
        tests = ["test_it.py"]
        [[component]]
        name = "broken"
        command = ["python", "component.py"]
        ready = { log = "component ready" }
        stop_timeout = 2
        """)
    )
    return path


@pytest.fixture
def system_temp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The system temporary folder, for this test: whatever lands there without being asked
    to has leaked."""
    folder = tmp_path / "system-tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    monkeypatch.delenv("REDLINE_WORK_DIR", raising=False)
    return folder


def test_a_failed_run_removes_its_workspace_and_keeps_its_logs_beside_the_recording(
    tmp_path: Path, system_temp: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    work = tmp_path / "work"
    monkeypatch.setenv("REDLINE_WORK_DIR", str(work))
    out = tmp_path / "out" / "run.mcap"
    with pytest.raises(ProcessExited) as caught:
        run_suite(_suite(tmp_path / "suite", GIVES_UP, 30.0), out)
    logs = tmp_path / "out" / "run.logs"
    message = str(caught.value)
    assert "giving up" in message and f"log {logs / 'broken.log'}" in message  # tail and path
    assert "giving up" in (logs / "broken.log").read_text()
    assert (logs / "redline-recorder.log").is_file() and (logs / "redline-monitor.log").is_file()
    assert work.is_dir() and list(work.iterdir()) == []
    assert list(system_temp.iterdir()) == []


def test_a_kept_workspace_lies_in_the_work_folder_and_a_good_run_leaves_nothing(
    tmp_path: Path, system_temp: Path
) -> None:
    suite, work = _suite(tmp_path / "suite", ALIVE, 0.3), tmp_path / "work"
    kept = run_suite(suite, tmp_path / "kept.mcap", keep_workspace=True, work_dir=work)
    assert kept.workspace is not None and kept.workspace.parent == work
    assert (kept.workspace / "run-meta.json").is_file()
    assert kept.logs == tmp_path / "kept.logs" and (kept.logs / "broken.log").is_file()
    clean = run_suite(suite, tmp_path / "clean.mcap", work_dir=work)
    assert clean.workspace is None and clean.logs is None
    assert not (tmp_path / "clean.logs").exists()
    assert list(work.iterdir()) == [kept.workspace]
    assert list(system_temp.iterdir()) == []


def test_redline_run_takes_the_work_folder_and_says_where_logs_go(
    tmp_path: Path, system_temp: Path
) -> None:
    redline = str(Path(sys.executable).parent / "redline")
    env = {**os.environ, "COLUMNS": "200", "TMPDIR": str(system_temp)}
    shown = subprocess.run([redline, "run", "--help"], capture_output=True, text=True, env=env)
    assert "--work" in shown.stdout and "REDLINE_WORK_DIR" in shown.stdout
    assert ".logs" in shown.stdout
    work = tmp_path / "work"
    failed = subprocess.run(
        [
            redline,
            "run",
            str(_suite(tmp_path / "suite", GIVES_UP, 30.0)),
            "--out",
            str(tmp_path / "run.mcap"),
            "--work",
            str(work),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert failed.returncode == 1, failed.stderr
    assert "giving up" in failed.stderr and "run.logs" in failed.stderr
    assert list(work.iterdir()) == [] and list(system_temp.iterdir()) == []
