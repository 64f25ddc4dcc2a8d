"""A run stopped by Ctrl-C or waiting for a liveliness token: a clean stop, never a hang (bad input
found before anything starts: tests/unit/test_runner_badinput.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from redline.agent.processes import RunError
from redline.agent.runner import run_suite
from redline.recording import read_recording

from tests.support.suites import quiet_suite as _suite

pytestmark = pytest.mark.usefixtures("workspaces_in_tmp_path")


LISTENING = """\
    import os, signal, threading, zenoh
    open("pid", "w").write(str(os.getpid()))
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set).start())

    def heard(_sample):
        open("heard", "w").close()

    with zenoh.open(zenoh.Config.from_env()) as session:
        subscriber = session.declare_subscriber("x/y", heard)
        print("component ready", flush=True)
        while not stop.wait(0.1):
            pass
    """


def _wait_for(path: Path, run: subprocess.Popen[str], timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert run.poll() is None, f"the run ended first (exit {run.returncode})"
        assert time.monotonic() < deadline, f"{path.name} did not appear within {timeout} s"
        time.sleep(0.05)


def test_ctrl_c_stops_every_process_and_leaves_a_readable_recording(tmp_path: Path) -> None:
    suite = _suite(
        tmp_path,
        """\
        from redline.testing import FixedRate, Phase, Publish, TestCase
        case = TestCase("long", [Phase("p", FixedRate(20, 60.0, Publish("x/y", b"1")))])
        """,
    )
    (tmp_path / "component.py").write_text(textwrap.dedent(LISTENING))
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
    _wait_for(tmp_path / "heard", run)  # the driver's traffic has reached the run's network
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
    signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set).start())
    with zenoh.open(zenoh.Config.from_env()) as session:
        token = session.liveliness().declare_token("lively/alive")
        heard = session.declare_subscriber("x/y", lambda sample: None)  # takes part in the run
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


def test_an_action_that_raises_is_named_with_where_in_the_test_module(tmp_path: Path) -> None:
    """A trial's raising action said only "RuntimeError: boom from my custom action": no file,
    no line, and no traceback in the run's logs. The error names the test module's line."""
    suite = _suite(
        tmp_path,
        """\
        from redline.testing import Phase, TestCase
        from redline.testing.actions import Action

        class Boom(Action):
            def run(self, ctx):
                raise RuntimeError("boom from my custom action")

        case = TestCase("c", [Phase("p", Boom())])
        """,
    )
    with pytest.raises(RunError) as caught:
        run_suite(suite, tmp_path / "out.mcap")
    said = str(caught.value)
    assert "RuntimeError: boom from my custom action" in said, said
    assert f"(raised at {tmp_path / 'test_it.py'}:6, in run)" in said, said
