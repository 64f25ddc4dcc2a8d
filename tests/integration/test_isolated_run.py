"""A job's run in a process of its own (`redline.agent.isolated`): what the run maps (zenoh's
shared-memory segments of the component it heard, eclipse-zenoh/zenoh#2787) goes when it ends,
so an agent does not grow from job to job; its errors and a stop keep their meaning."""

from __future__ import annotations

import os
import re
import signal
import textwrap
from pathlib import Path

import pytest
from redline.agent.isolated import ChildFailed, run_isolated
from redline.recording import read_recording

pytestmark = pytest.mark.usefixtures("workspaces_in_tmp_path")

COMPONENT = """\
    import signal, threading, zenoh
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set).start())
    with zenoh.open(zenoh.Config.from_env()) as session:
        sub = session.declare_subscriber("x/y", lambda sample: None)
        print("ready", flush=True)
        stop.wait()
    """


def _suite(tmp_path: Path, test: str) -> Path:
    (tmp_path / "component.py").write_text(textwrap.dedent(COMPONENT))
    (tmp_path / "test_it.py").write_text(textwrap.dedent(test))
    path = tmp_path / "redline.toml"
    path.write_text(
        'name = "isolated"\ntests = ["test_it.py"]\n[[component]]\nname = "c"\n'
        'command = ["python", "component.py"]\nready = { log = "ready" }\nstop_timeout = 2\n'
    )
    return path


def _long_suite_saying_pids(tmp_path: Path) -> Path:
    """A suite of a minute's phase whose driver and component write their pids to
    ``driver.pid`` and ``component.pid``, to see them end."""
    suite = _suite(
        tmp_path,
        f"""\
        import os
        from pathlib import Path
        from redline.testing import FixedRate, Phase, Publish, TestCase
        Path({str(tmp_path / "driver.pid")!r}).write_text(str(os.getpid()))
        case = TestCase("long", [Phase("p", FixedRate(20, 60.0, Publish("x/y", b"1")))])
        """,
    )
    (tmp_path / "component.py").write_text(
        textwrap.dedent(COMPONENT).replace(
            'print("ready", flush=True)',
            f'open({str(tmp_path / "component.pid")!r}, "w").write(str(__import__("os").getpid()))'
            '\n    print("ready", flush=True)',
        )
    )
    return suite


def test_a_jobs_run_happens_in_a_process_that_ends_with_it(tmp_path: Path) -> None:
    test = f"""\
        import os
        from pathlib import Path
        from redline.testing import FixedRate, Phase, Publish, TestCase
        Path({str(tmp_path / "pid")!r}).write_text(str(os.getpid()))
        case = TestCase("short", [Phase("p", FixedRate(20, 0.3, Publish("x/y", b"1" * 8192)))])
        """
    result = run_isolated(_suite(tmp_path, test), tmp_path / "out.mcap", {"job": "7"})
    driver = int((tmp_path / "pid").read_text())
    assert driver != os.getpid()
    with pytest.raises(ProcessLookupError):
        os.kill(driver, 0)  # gone, and what it mapped with it
    recording = read_recording(result.recording)
    assert result.segments == 1 and recording.run["status"] == "ok"
    assert recording.run["job"] == "7" and recording.traffic["x/y"] == 6


def test_a_run_that_cannot_start_fails_naming_why(tmp_path: Path) -> None:
    suite = _suite(tmp_path, "raise RuntimeError('no such robot')\n")
    with pytest.raises(ChildFailed, match="no such robot") as failed:
        run_isolated(suite, tmp_path / "out.mcap", {})
    # the whole traceback too, for the agent's log: a trial's run logs kept none
    assert failed.value.trace.startswith("Traceback (most recent call last):")
    assert 'test_it.py", line 1' in failed.value.trace, failed.value.trace


def test_an_agent_that_stops_mid_run_ends_the_run_and_its_recording_says_so(
    tmp_path: Path,
) -> None:
    """The agent's second signal raises while it waits: the child is told to stop, stops the
    component and finishes the recording as ``terminated`` before the agent goes on."""
    test = """\
        from redline.testing import FixedRate, Phase, Publish, TestCase
        case = TestCase("long", [Phase("p", FixedRate(20, 60.0, Publish("x/y", b"1")))])
        """

    class Stopping(BaseException):
        pass

    def stop(*_: object) -> None:
        raise Stopping

    previous = signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, 8.0)
    try:
        with pytest.raises(Stopping):
            run_isolated(_suite(tmp_path, test), tmp_path / "out.mcap", {})
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert read_recording(tmp_path / "out.mcap", strict=False).run["status"] == "terminated"


def test_a_run_whose_agent_is_killed_stops_and_takes_its_component_with_it(
    tmp_path: Path,
) -> None:
    """An agent SIGKILLed mid-run (out of memory, a supervisor's last word) leaves no suite
    running unsupervised beside the next agent: the run's process is told by the kernel
    (PR_SET_PDEATHSIG), and its runner stops the component."""
    import subprocess
    import sys
    import time

    suite = _long_suite_saying_pids(tmp_path)
    agent = subprocess.Popen(
        [sys.executable, "-c", "import sys; from pathlib import Path; "
         "from redline.agent.isolated import run_isolated; "
         "run_isolated(Path(sys.argv[1]), Path(sys.argv[2]), {})",
         str(suite), str(tmp_path / "out.mcap")]
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while not (tmp_path / "driver.pid").exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        while not (tmp_path / "component.pid").exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        driver = int((tmp_path / "driver.pid").read_text())
        component = int((tmp_path / "component.pid").read_text())
        time.sleep(1.0)  # the phase is under way
        agent.kill()
        agent.wait()
        for pid in (driver, component):
            while time.monotonic() < deadline:
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                time.sleep(0.2)
            else:
                os.kill(pid, signal.SIGKILL)
                raise AssertionError(f"process {pid} outlived the killed agent")
    finally:
        agent.kill()


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not reaped, does not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def test_a_run_killed_outright_leaves_no_process_behind_it(tmp_path: Path) -> None:
    """A run's process SIGKILLed (out of memory) cannot stop what it started: its component,
    in a session of its own, ran on under init beside the agent's next job. The agent adopts
    the orphans and ends them; the job fails naming that."""
    import subprocess
    import sys
    import time

    suite = _long_suite_saying_pids(tmp_path)
    said = tmp_path / "said"
    agent = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from pathlib import Path; "
         "from redline.agent import isolated\n"
         "from redline.agent.isolated import ChildFailed, adopt_orphans, run_isolated\n"
         "assert adopt_orphans()\n"
         "try: run_isolated(Path(sys.argv[1]), Path(sys.argv[2]), {})\n"
         "except ChildFailed as exc: Path(sys.argv[3]).write_text(str(exc) + "
         "' / children left: ' + str(len(isolated._children())))\n"
         "time.sleep(60)",
         str(suite), str(tmp_path / "out.mcap"), str(said)]
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        for name in ("driver.pid", "component.pid"):
            while not (tmp_path / name).exists() and time.monotonic() < deadline:
                time.sleep(0.2)
        driver = int((tmp_path / "driver.pid").read_text())
        component = int((tmp_path / "component.pid").read_text())
        time.sleep(1.0)  # the phase is under way
        os.kill(driver, signal.SIGKILL)
        while not said.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert "ended without a result" in said.read_text()
        # the component, and the run's own helpers (its recorder's)
        assert re.search(r"; [1-9][0-9]* process\(es\) it had started ended", said.read_text())
        # what the agent itself started lives on: multiprocessing's resource tracker, which the
        # spawn of the run's process started, was taken for an orphan and killed
        assert said.read_text().endswith(" / children left: 1"), said.read_text()
        assert not _alive(component), "the component outlived its killed run"
        assert Path(f"/proc/{component}").exists() is False  # reaped, not a zombie
    finally:
        agent.kill()
        agent.wait()
        if (tmp_path / "component.pid").exists():
            component = int((tmp_path / "component.pid").read_text())
            if _alive(component):
                os.kill(component, signal.SIGKILL)
