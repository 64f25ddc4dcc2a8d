"""Bad input to a run: each a clear error before anything starts, or a clean stop; never a hang."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest
from redline.agent.processes import RunError
from redline.agent.runner import run_suite
from redline.recording import read_recording
from redline.testing import ValidationError

COMPONENT = """\
    import os, signal, threading
    open("pid", "w").write(str(os.getpid()))
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print("component ready", flush=True)
    while not stop.wait(0.1):
        pass
    """


def _suite(tmp_path: Path, test: str) -> Path:
    (tmp_path / "component.py").write_text(textwrap.dedent(COMPONENT))
    (tmp_path / "test_it.py").write_text(textwrap.dedent(test))
    path = tmp_path / "redline.toml"
    path.write_text(
        textwrap.dedent("""\
        name = "bad"
        tests = ["test_it.py"]
        [[component]]
        name = "quiet"
        command = ["python", "component.py"]
        ready = { log = "component ready" }
        """)
    )
    return path


@pytest.fixture(autouse=True)
def workspaces_in_tmp_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))


def test_missing_parameter_fails_before_any_process_starts(tmp_path: Path) -> None:
    suite = _suite(
        tmp_path,
        """\
        from redline.testing import Cartesian, FixedRate, Param, Phase, Publish, TestCase
        case = TestCase("c", [Phase("p", FixedRate(Param("rate"), 1, Publish("k", b"")))],
                        Cartesian(rat=[1]))
        """,
    )
    with pytest.raises(ValidationError, match="phase 'p': parameter 'rate' is missing"):
        run_suite(suite, tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists() and not (tmp_path / "pid").exists()


def test_malformed_key_expression_fails_before_any_process_starts(tmp_path: Path) -> None:
    suite = _suite(
        tmp_path,
        """\
        from redline.testing import Phase, Publish, TestCase
        case = TestCase("c", [Phase("p", Publish("robot//scan", b""))])
        """,
    )
    with pytest.raises(ValidationError, match="'robot//scan' is not a valid key expression"):
        run_suite(suite, tmp_path / "out.mcap")
    assert not (tmp_path / "pid").exists()


def test_test_module_with_an_error_is_named_with_its_line(tmp_path: Path) -> None:
    suite = _suite(
        tmp_path,
        """\
        from redline.testing import Phase, Static, TestCase
        case = TestCase("c", [Phase("p", Static(1))])
        broken = 1 / 0
        """,
    )
    with pytest.raises(
        RunError,
        match=r"test_it.py:3: cannot import test module: "
        r"ZeroDivisionError",
    ):
        run_suite(suite, tmp_path / "out.mcap")


def test_ctrl_c_stops_every_process_and_leaves_a_readable_recording(tmp_path: Path) -> None:
    suite = _suite(
        tmp_path,
        """\
        from redline.testing import FixedRate, Phase, Publish, TestCase
        case = TestCase("long", [Phase("p", FixedRate(20, 60.0, Publish("x/y", b"1")))])
        """,
    )
    out = tmp_path / "out.mcap"
    run = subprocess.Popen(
        [str(Path(sys.executable).parent / "redline"), "run", str(suite), "--out", str(out)],
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert run.stderr is not None
    for line in run.stderr:
        if "long/p" in line:  # the segment has begun
            break
    time.sleep(0.5)
    run.send_signal(signal.SIGINT)
    rest = run.stderr.read()
    assert run.wait(60) == 130, rest
    assert "interrupted" in rest
    recording = read_recording(out)  # strict: a finished Redline recording
    assert recording.run["status"] == "interrupted" and recording.run["signal"] == "SIGINT"
    assert [m["event"] for m in recording.markers] == ["begin", "end"]
    assert recording.traffic["x/y"] > 0
    assert not Path(f"/proc/{int((tmp_path / 'pid').read_text())}").exists()


LIVELY = """\
    import signal, threading, zenoh
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with zenoh.open(zenoh.Config.from_env()) as session:
        token = session.liveliness().declare_token("lively/alive")
        while not stop.wait(0.1):
            pass
    """


def test_component_ready_by_liveliness_token_runs_and_a_missing_token_times_out(
    tmp_path: Path,
) -> None:
    test = """\
        from redline.testing import Phase, Publish, TestCase
        case = TestCase("c", [Phase("p", Publish("x/y", b"1"))])
        """
    suite = _suite(tmp_path, test)
    (tmp_path / "component.py").write_text(textwrap.dedent(LIVELY))
    text = suite.read_text().replace(
        '{ log = "component ready" }', '{ liveliness = "lively/*" }\nstart_timeout = 5'
    )
    suite.write_text(text)
    assert read_recording(run_suite(suite, tmp_path / "ok.mcap").recording).run["status"] == "ok"
    suite.write_text(text.replace("lively/*", "other/*"))
    with pytest.raises(RunError, match="waiting for a zenoh liveliness token on 'other/\\*'"):
        run_suite(suite, tmp_path / "never.mcap")
