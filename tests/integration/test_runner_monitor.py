"""The monitor's samplers on real processes: trees of children, threads, memory, files, host.

Serial: they compare the CPU of busy and idle processes, which other tests' load would move.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator

import pytest
from redline.agent.procstat import ProcessSampler
from redline.agent.sampling import HostSampler, TreeSampler

pytestmark = pytest.mark.serial

PARENT_WITH_BUSY_CHILD = """\
    import subprocess, sys, time
    child = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    print(child.pid, flush=True)
    child.wait()
    print("reaped", flush=True)
    time.sleep(60)
    """

SLEEPY_THREADS = """\
    import threading, time
    def nap():
        while True:
            time.sleep(0.001)
    for _ in range(3):
        threading.Thread(target=nap, daemon=True).start()
    files = [open("/proc/self/stat") for _ in range(40)]
    print("ready", flush=True)
    time.sleep(60)
    """


@pytest.fixture
def spawn() -> Iterator[object]:
    started: list[subprocess.Popen[str]] = []

    def start(code: str) -> subprocess.Popen[str]:
        process = subprocess.Popen(
            [sys.executable, "-c", textwrap.dedent(code)],
            stdout=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        started.append(process)
        return process

    yield start
    for process in started:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def _samples(sampler: TreeSampler | ProcessSampler, count: int, **options: bool) -> list[dict]:
    values = []
    for _ in range(count):
        time.sleep(0.1)
        values.append(sampler.sample(**options))
    return values


def test_tree_includes_a_busy_child_and_forgets_it_when_it_exits(spawn) -> None:
    parent = spawn(PARENT_WITH_BUSY_CHILD)
    child_pid = int(parent.stdout.readline())
    tree = TreeSampler("parent", parent.pid)
    alone = ProcessSampler("parent", parent.pid)
    together = _samples(tree, 6)
    by_itself = alone.sample()["cpu_percent"]
    assert together[-1]["processes"] == 2 and child_pid in tree.members
    assert sum(s["cpu_percent"] for s in together[1:]) / 5 > 10 * max(1.0, by_itself)
    os.kill(child_pid, signal.SIGKILL)
    assert parent.stdout.readline().strip() == "reaped"
    tree.rescan()
    assert child_pid not in tree.members and tree.sample()["processes"] == 1
    alone.close()
    tree.close()


def test_a_reused_pid_is_sampled_as_a_new_process(spawn) -> None:
    parent = spawn(PARENT_WITH_BUSY_CHILD)
    child_pid = int(parent.stdout.readline())
    tree = TreeSampler("parent", parent.pid)
    tree.rescan()
    first = tree.members[child_pid]
    first.start_time -= 1  # as if another process had held this PID before
    tree.rescan()
    assert tree.members[child_pid] is not first
    tree.rescan()
    assert tree.members[child_pid] is tree.members[child_pid]
    tree.close()


def test_context_switches_are_summed_over_threads_and_files_counted(spawn) -> None:
    process = spawn(SLEEPY_THREADS)
    assert process.stdout.readline().strip() == "ready"
    sampler = ProcessSampler("sleepy", process.pid)
    main_before = _main_thread_switches(process.pid)
    samples = _samples(sampler, 6, detail=True)
    main_gained = _main_thread_switches(process.pid) - main_before
    switches = sum(s["ctx_voluntary_per_s"] for s in samples) / 6
    assert switches > 20 * max(1, main_gained), (switches, main_gained)
    last = samples[-1]
    assert last["threads"] == 4 and last["fds"] >= 40
    assert 0 < last["uss_bytes"] <= last["pss_bytes"] <= last["rss_bytes"] <= last["vms_bytes"]
    assert "cpu_user_percent" in last and "cpu_system_percent" in last
    sampler.close()


def _main_thread_switches(pid: int) -> int:
    with open(f"/proc/{pid}/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("voluntary_"))


def test_host_sampler_reports_cpu_shares_including_steal_and_load() -> None:
    host = HostSampler()
    samples = _samples(host, 6)  # type: ignore[arg-type]
    host.close()
    last = samples[-1]
    for counter in (
        "cpu_percent",
        "cpu_user_percent",
        "cpu_system_percent",
        "cpu_iowait_percent",
        "cpu_steal_percent",
    ):
        assert 0 <= last[counter] <= 100, (counter, last)
    assert last["cpu_percent"] == pytest.approx(
        last["cpu_user_percent"] + last["cpu_system_percent"], abs=0.01
    )
    assert last["load_1m"] >= 0


def _child(code: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)])


def _samples_of(pid: int, count: int) -> list[dict[str, float]]:
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
        busy_cpu = [s["cpu_percent"] for s in _samples_of(busy.pid, 8)]
        idle_cpu = [s["cpu_percent"] for s in _samples_of(idle.pid, 8)]
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
        samples = _samples_of(child.pid, 15)
    finally:
        child.kill()
        child.wait()
    assert all(s["cpu_percent"] >= 0 for s in samples)
    assert max(s["threads"] for s in samples) >= 2
    assert all(s["rss_bytes"] > 1_000_000 for s in samples)
