"""The monitor's own CPU cost per monitored process at 10 Hz, against an idle zenoh client.

Starts N target processes that look like components (a zenoh peer session with its threads),
then for the same wall time runs (a) the monitor process sampling all N at 10 Hz and (b) a
reference process that opens the same zenoh client session and does nothing. The monitor's cost
is its CPU time minus the reference's, per target, as % of one core; the target is <= 0.5 %.

Run: .venv/bin/python benchmarks/bench_monitor.py   (prints figures; not a test)
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from redline.agent.network import RunNetwork

TARGETS, SECONDS, RATE = 4, 10.0, 10
TICKS = os.sysconf("SC_CLK_TCK")
COMPONENT = """\
import time, zenoh
with zenoh.open(zenoh.Config.from_env()) as session:
    session.declare_subscriber("bench/**", lambda s: None)
    print("ready", flush=True)
    time.sleep(600)
"""
IDLE_CLIENT = """\
import signal, threading
from redline.agent.interrupts import set_on_signals
from redline.agent.network import client_settings_from_env, open_client
stop = threading.Event()
set_on_signals(stop, signal.SIGTERM)
with open_client(client_settings_from_env()) as session:
    print("redline-monitor ready", flush=True)
    while not stop.wait(0.2):
        pass
"""


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat", "rb") as stat:
        fields = stat.read().rsplit(b")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def measure(argv: list[str], env: dict[str, str]) -> float:
    """CPU seconds a helper process uses over SECONDS once it is ready."""
    process = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    process.stdout.readline()
    before = cpu_seconds(process.pid)
    time.sleep(SECONDS)
    used = cpu_seconds(process.pid) - before
    process.terminate()
    process.wait()
    return used


def main() -> None:
    with RunNetwork() as network:
        config = network.write_component_config(
            Path(tempfile.gettempdir()) / f"bench-monitor-{os.getpid()}.json"
        )
        env = {
            **os.environ,
            "ZENOH_CONFIG": str(config),
            "REDLINE_ZENOH": json.dumps(network.client_settings()),
        }
        targets = [
            subprocess.Popen(
                [sys.executable, "-c", COMPONENT], env=env, stdout=subprocess.PIPE, text=True
            )
            for _ in range(TARGETS)
        ]
        for target in targets:
            assert target.stdout is not None
            target.stdout.readline()
        try:
            names = [f"c{i}={t.pid}" for i, t in enumerate(targets)]
            monitor = measure(
                [sys.executable, "-m", "redline.agent.monitor", "--rate", str(RATE), *names], env
            )
            idle = measure([sys.executable, "-c", IDLE_CLIENT], env)
        finally:
            for target in targets:
                target.kill()
                target.wait()
            config.unlink()
    per_target = 100 * (monitor - idle) / SECONDS / TARGETS
    print(
        f"monitor at {RATE} Hz over {TARGETS} targets (+ host), {SECONDS:.0f} s: "
        f"{100 * monitor / SECONDS:.2f} % of a core; idle zenoh client "
        f"{100 * idle / SECONDS:.2f} %; ratio {monitor / max(idle, 1e-9):.2f}"
    )
    print(
        f"monitor cost per monitored process: {per_target:.3f} % of one core "
        f"(target <= 0.5 %; ticks are 10 ms, so +-{100 / TICKS / SECONDS / TARGETS:.3f} %)"
    )


if __name__ == "__main__":
    main()
