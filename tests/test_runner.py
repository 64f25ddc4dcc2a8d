"""The runner on real zenoh: the objectbuilder suite end to end, failures, and the monitor."""

from __future__ import annotations

import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest
from redline.agent.monitor import ProcessSampler
from redline.agent.processes import ProcessExited, RunError
from redline.agent.runner import RunResult, run_suite
from redline.recording import Recording, canonical_params, read_recording

ROOT = Path(__file__).resolve().parents[1]
OBJECTBUILDER = ROOT / "examples" / "objectbuilder" / "perf" / "redline.toml"

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def objectbuilder_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[RunResult, Recording]:
    out = tmp_path_factory.mktemp("run") / "objectbuilder.mcap"
    result = run_suite(OBJECTBUILDER, out, run_metadata={"revision_title": "r1", "job_id": "7"})
    return result, read_recording(out)


def test_recording_holds_counters_for_every_measured_segment(objectbuilder_run) -> None:
    _, recording = objectbuilder_run
    samples = recording.series_samples()
    measured = [s for s in recording.segments() if not s.warmup]
    assert len(measured) == 4
    for segment in measured:
        for counter in ("cpu_percent", "rss_bytes", "threads"):
            values = [
                v
                for k, v in samples.items()
                if k.process == "objectbuilder"
                and k.counter == counter
                and k.phase == segment.phase
                and k.params == canonical_params(segment.params)
            ]
            assert values and values[0], f"no {counter} in {segment}"
    processes = {c["process"] for c in recording.counters}
    assert processes == {"objectbuilder", "host", "redline"}  # redline: the run's own CPU
    assert all(c["pid"] > 0 for c in recording.counters if c["process"] == "objectbuilder")
    counters = {k.counter for k in samples if k.process == "objectbuilder"}
    assert {
        "cpu_user_percent",
        "cpu_system_percent",
        "vms_bytes",
        "uss_bytes",
        "pss_bytes",
        "ctx_voluntary_per_s",
        "ctx_involuntary_per_s",
        "fds",
        "processes",
    } <= counters
    assert {"cpu_steal_percent", "load_1m"} <= {k.counter for k in samples if k.process == "host"}


def test_recording_holds_markers_traffic_and_driver_metrics(objectbuilder_run) -> None:
    _, recording = objectbuilder_run
    names = {
        (s.phase, f"legs={s.params['legs']},rate={s.params['rate']}") for s in recording.segments()
    }
    expected = {f"legs={legs},rate={rate}" for legs in (2, 8) for rate in (10, 40)}
    assert names == {(phase, name) for phase in ("warmup", "steady") for name in expected}
    assert recording.traffic["objectbuilder/legs"] > 0
    assert recording.traffic["objectbuilder/persons"] > 0
    steady = [d for d in recording.driver if d["phase"] == "steady"]
    rates = [d for d in steady if d["action"] == "FixedRate"]
    assert len(rates) == 4 and {d["iterations"] for d in rates} == {20, 80}  # 2 s, 10 and 40 Hz
    published = [d for d in steady if d["action"] == "Publish"]  # what FixedRate put, per key
    assert {d["key"] for d in published} == {"objectbuilder/legs", "objectbuilder/pose"}
    assert len(published) == 8 and {d["published"] for d in published} == {20, 80}


def test_each_parameter_set_is_warmed_up_right_before_it_is_measured(objectbuilder_run) -> None:
    _, recording = objectbuilder_run
    ordered = sorted(recording.segments(), key=lambda s: s.begin_ns)
    assert [s.phase for s in ordered] == ["warmup", "steady"] * 4
    pairs = zip(ordered[::2], ordered[1::2], strict=True)
    assert all(warm.params == steady.params for warm, steady in pairs)


def test_recording_metadata_names_run_host_and_recorder(objectbuilder_run) -> None:
    result, recording = objectbuilder_run
    run = recording.run
    assert run["revision_title"] == "r1" and run["job_id"] == "7"
    assert run["component"] == "objectbuilder" and run["suite"] == "objectbuilder"
    assert len(run["suite_sha256"]) == 64 and run["status"] == "ok"
    assert run["zenoh_version"] and run["redline_version"] and run["ended_at"] > run["started_at"]
    host = recording.metadata["redline.host"]
    assert host["governor_state"] in {"pinned", "unavailable", "denied"}
    assert int(host["cpu_cores"]) >= 1 and host["kernel"] and "load_1m" in host
    counts = recording.metadata["redline.recorder"]
    assert int(counts["written"]) == int(counts["received"]) - int(counts["dropped"]) > 0
    assert result.workspace is None  # removed after a successful run


def test_cpu_grows_with_the_number_of_legs(objectbuilder_run) -> None:
    _, recording = objectbuilder_run
    means = {}
    for key, values in recording.series_samples().items():
        if key.counter == "cpu_percent" and key.process == "objectbuilder":
            means[key.params] = sum(values) / len(values)
    for rate in (10, 40):  # 28 leg pairs against 1: the quadratic work must show at each rate
        few = means[f'{{"legs":2,"rate":{rate}}}']
        many = means[f'{{"legs":8,"rate":{rate}}}']
        assert many > 2 * few, means


@pytest.fixture(autouse=True)
def workspaces_in_tmp_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Workspaces kept after a failure land in the test's own folder, not in /tmp."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))


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
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
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


def _child(code: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)])


def _samples(pid: int, count: int) -> list[dict[str, float]]:
    sampler = ProcessSampler("child", pid)
    values = []
    for _ in range(count):
        time.sleep(0.1)
        values.append(sampler.sample(detail=True))  # threads are re-listed on detail samples
    sampler.close()
    return values


def test_monitor_tells_a_busy_process_from_an_idle_one() -> None:
    busy = _child("while True: pass")
    idle = _child("import time; time.sleep(60)")
    try:
        busy_cpu = [s["cpu_percent"] for s in _samples(busy.pid, 8)]
        idle_cpu = [s["cpu_percent"] for s in _samples(idle.pid, 8)]
    finally:
        for child in (busy, idle):
            child.kill()
            child.wait()
    assert sum(busy_cpu) / 8 > 10 * max(1.0, sum(idle_cpu) / 8), (busy_cpu, idle_cpu)
    assert all(v >= 0 for v in busy_cpu + idle_cpu)


def test_monitor_counts_threads_and_never_goes_negative_when_threads_exit() -> None:
    child = _child("""\
        import threading, time
        def spin(seconds):
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                pass
        while True:
            workers = [threading.Thread(target=spin, args=(0.15,)) for _ in range(3)]
            for w in workers: w.start()
            for w in workers: w.join()
        """)
    try:
        samples = _samples(child.pid, 15)
    finally:
        child.kill()
        child.wait()
    assert all(s["cpu_percent"] >= 0 for s in samples)
    assert max(s["threads"] for s in samples) >= 2
    assert all(s["rss_bytes"] > 1_000_000 for s in samples)
