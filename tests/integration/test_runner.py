"""The runner on real zenoh: components that fail, are never ready or are ready by a key, and
several executions of one suite (the objectbuilder run: test_runner_objectbuilder.py)."""

from __future__ import annotations

import tempfile
import textwrap
from pathlib import Path

import pytest
from redline.agent.processes import ProcessExited, RunError
from redline.agent.runner import run_executions, run_suite
from redline.recording import read_recording

from tests.support import ROOT

OBJECTBUILDER = ROOT / "examples" / "objectbuilder" / "perf" / "redline.toml"
ECHO = ROOT / "examples" / "echo" / "perf" / "redline.toml"

pytestmark = pytest.mark.usefixtures("workspaces_in_tmp_path")


def _suite(tmp_path: Path, component: str, ready: str, test: str) -> Path:
    (tmp_path / "component.py").write_text(textwrap.dedent(component))
    (tmp_path / "test_it.py").write_text(textwrap.dedent(test))
    path = tmp_path / "redline.toml"
    path.write_text(
        textwrap.dedent(f"""\
        name = "failing"
        tests = ["test_it.py"]
        [[component]]
        name = "broken"
        command = ["python", "component.py"]
        ready = {ready}
        start_timeout = 3
        stop_timeout = 2
        """)
    )
    return path


LONG_TEST = """\
    from redline.testing import FixedRate, Phase, Publish, TestCase
    case = TestCase("long", [Phase("p", FixedRate(20, 60.0, Publish("x/y", b"1")))])
    """


def test_component_that_exits_early_fails_the_run_with_its_exit_code(tmp_path: Path) -> None:
    component = """\
        import sys, time
        print("component ready", flush=True)
        time.sleep(1.0)
        print("giving up", flush=True)
        sys.exit(3)
        """
    suite = _suite(tmp_path, component, '{ log = "component ready" }', LONG_TEST)
    out = tmp_path / "out.mcap"
    with pytest.raises(ProcessExited) as caught:
        run_suite(suite, out)
    assert caught.value.code == 3 and caught.value.name == "broken"
    assert "exit code 3" in str(caught.value) and "giving up" in str(caught.value)
    recording = read_recording(out)  # finished despite the failure, with what was captured
    assert recording.run["status"] == "failed" and "exit code 3" in recording.run["error"]
    assert [m["event"] for m in recording.markers] == ["begin", "end"]
    assert recording.traffic["x/y"] > 0
    # the component's own output travels with the recording, to the server's execution page
    assert recording.logs["broken"] == "component ready\ngiving up\n"


def test_component_never_ready_times_out_and_is_stopped(tmp_path: Path) -> None:
    component = """\
        import os, time
        open("pid", "w").write(str(os.getpid()))
        time.sleep(600)
        """
    suite = _suite(tmp_path, component, '{ log = "never printed" }', LONG_TEST)
    with pytest.raises(RunError, match="broken was not ready within 3 s") as caught:
        run_suite(suite, tmp_path / "out.mcap")
    assert "never printed" in str(caught.value)
    pid = int((tmp_path / "pid").read_text())
    assert not Path(f"/proc/{pid}").exists()


def test_component_ready_by_zenoh_key_runs_through(tmp_path: Path) -> None:
    component = """\
        import signal, threading, zenoh
        stop = threading.Event()
        signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set).start())
        with zenoh.open(zenoh.Config.from_env()) as session:
            while not stop.wait(0.1):
                session.put("demo/alive", b"1")
        """
    test = """\
        from redline.testing import FixedRate, Phase, Publish, TestCase
        case = TestCase("short", [Phase("p", FixedRate(20, 0.3, Publish("x/y", b"1")))])
        """
    suite = _suite(tmp_path, component, '{ key = "demo/alive" }', test)
    result = run_suite(suite, tmp_path / "out.mcap", keep_workspace=True)
    recording = read_recording(result.recording)
    assert result.segments == 1 and recording.run["status"] == "ok"
    assert recording.traffic["demo/alive"] > 0 and recording.traffic["x/y"] == 6
    assert result.logs is not None and (result.logs / "broken.log").exists()
    assert result.workspace is not None and result.workspace.parent == tmp_path


def test_a_suites_affinity_pins_the_component_and_is_recorded_in_the_run(tmp_path: Path) -> None:
    (tmp_path / "component.py").write_text(
        textwrap.dedent("""\
        import os, signal, threading
        open("cores", "w").write(str(sorted(os.sched_getaffinity(0))))
        stop = threading.Event()
        signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set).start())
        print("component ready", flush=True)
        while not stop.wait(0.1):
            pass
        """)
    )
    (tmp_path / "test_it.py").write_text(
        "from redline.testing import Phase, Sleep, TestCase\n"
        "case = TestCase('idle', [Phase('idle', Sleep(0.3))])\n"
    )
    suite = tmp_path / "redline.toml"
    suite.write_text(
        textwrap.dedent("""\
        name = "pinned"
        tests = ["test_it.py"]
        [affinity]
        components = [0]
        driver = [0]
        monitor = [0]
        [[component]]
        name = "pinned"
        command = ["python", "component.py"]
        ready = { log = "component ready" }
        """)
    )
    recording = read_recording(run_suite(suite, tmp_path / "out.mcap").recording)
    assert recording.run["affinity"] == '{"components": [0], "driver": [0], "monitor": [0]}'
    assert (tmp_path / "cores").read_text() == "[0]"


def test_two_executions_restart_the_component_and_record_one_file_each(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    results = run_executions(
        ECHO,
        tmp_path / "echo.mcap",
        executions=2,
        only=["relay", "replay"],
        overrides={"speed": 4.0},
    )
    assert [r.recording.name for r in results] == ["echo-1.mcap", "echo-2.mcap"]
    pids = []
    for index, result in enumerate(results, start=1):
        recording = read_recording(result.recording)
        assert recording.run["execution"] == str(index) and recording.run["executions"] == "2"
        assert [(s.case, s.params) for s in recording.segments()] == [
            ("relay", {"points": 10, "rate": 100}),
            ("relay", {"points": 500, "rate": 100}),
            ("replay", {"speed": 4.0}),
        ]
        listened = [d for d in recording.driver if d["action"] == "Listen"]
        assert [d["received"] for d in listened] == [100, 100, 50]
        assert [d.get("lost") for d in listened] == [0, 0, None]  # replayed scans carry no seq
        replayed = [d for d in recording.driver if d["action"] == "Replay"]
        assert replayed[0]["messages"] == 50
        pids.append({c["pid"] for c in recording.counters if c["process"] == "echo"})
    assert len(pids[0]) == len(pids[1]) == 1 and pids[0] != pids[1]
