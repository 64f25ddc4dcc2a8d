"""The monitor process: samples each component's process tree and the host, publishes counters.

    python -m redline.agent.monitor --rate 10 objectbuilder=1234 [name=pid ...]

Client settings for zenoh come as JSON in ``REDLINE_ZENOH``. Each sample is published as
``{"t_ns", "pid", "process", "values": {...}}`` on ``@redline/counters/<name>``, the host's on
``@redline/counters/host`` (process ``host``, pid 0). Per component (its process and every
descendant, summed; see `sampling.TreeSampler`): ``cpu_percent`` (nanosecond run time of every
thread, from schedstat), ``cpu_user_percent`` and ``cpu_system_percent`` (ticks, over >= 0.5 s
windows), ``rss_bytes``, ``vms_bytes``, ``threads``, ``processes``, ``io_read_bytes`` and
``io_write_bytes`` (cumulative); once a second also ``uss_bytes``, ``pss_bytes``, ``fds``,
``ctx_voluntary_per_s`` and ``ctx_involuntary_per_s`` (summed over threads). Host: ``cpu_percent``,
``cpu_user_percent``, ``cpu_system_percent``, ``cpu_iowait_percent``, ``cpu_steal_percent`` (% of
all CPUs) and ``load_1m``. Redline's own processes (``--own PID``: the runner with its driver
and router, the recorder, and the monitor itself; each alone, not its children) are summed as
``@redline/counters/redline`` (process ``redline``): ``cpu_percent``, so that what else used the
host during a phase can be told (`redline.recording.disturbance`).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time

import zenoh
from redline.agent.interrupts import set_on_signals
from redline.agent.network import client_settings_from_env, open_client
from redline.agent.procstat import ProcessSampler
from redline.agent.sampling import HostSampler, TreeSampler
from redline.recording.format import COUNTERS_PREFIX, OWN_PROCESS
from redline.recording.format import HOST_PROCESS as HOST

DETAIL_S = 1.0  # USS/PSS (~1 ms a read), thread lists, context switches, fds: once a second

__all__ = ["HOST", "ProcessSampler", "main", "run"]


def _targets(specs: list[str]) -> list[tuple[str, int]]:
    targets = []
    for spec in specs:
        name, _, pid = spec.partition("=")
        if not name or not pid.isdigit():
            raise SystemExit(f"monitor: expected NAME=PID, got {spec!r}")
        targets.append((name, int(pid)))
    return targets


class _Publishing:
    """One publisher per process name; the message layout of format.py."""

    def __init__(self, session: zenoh.Session, names: list[str]) -> None:
        self._publishers = {
            name: session.declare_publisher(COUNTERS_PREFIX + name) for name in names
        }

    def put(self, name: str, pid: int, values: dict[str, float]) -> None:
        self._publishers[name].put(
            json.dumps({"t_ns": time.time_ns(), "pid": pid, "process": name, "values": values})
        )


def _sample_own(own: list[ProcessSampler], out: _Publishing) -> None:
    """Redline's own processes' CPU, summed (a process that is gone is dropped)."""
    total = 0.0
    for sampler in list(own):
        try:
            total += sampler.sample()["cpu_percent"]
        except OSError:
            own.remove(sampler)
            sampler.close()
    out.put(OWN_PROCESS, 0, {"cpu_percent": round(total, 3)})


def _sample_all(
    samplers: list[TreeSampler], host: HostSampler | None, out: _Publishing, detail: bool
) -> None:
    for sampler in list(samplers):
        try:
            values = sampler.sample(detail=detail)
        except OSError:
            print(f"redline-monitor: {sampler.name} (pid {sampler.pid}) is gone", flush=True)
            samplers.remove(sampler)
            sampler.close()
            continue
        out.put(sampler.name, sampler.pid, values)
    if host is not None:
        out.put(HOST, 0, host.sample())


def run(
    targets: list[tuple[str, int]],
    rate: float,
    stop: threading.Event,
    with_host: bool = True,
    own: list[int] | None = None,
) -> None:
    """Sample every target at ``rate`` Hz on absolute deadlines until ``stop`` is set; ``own``:
    Redline's own processes, whose CPU is summed as process ``redline``."""
    samplers = [TreeSampler(name, pid) for name, pid in targets]
    host = HostSampler() if with_host else None
    mine = (
        [ProcessSampler(OWN_PROCESS, pid) for pid in dict.fromkeys([*(own or []), os.getpid()])]
        if own is not None
        else []
    )
    with open_client(client_settings_from_env()) as session:
        out = _Publishing(
            session,
            [s.name for s in samplers] + ([HOST] if host else []) + ([OWN_PROCESS] if mine else []),
        )
        print(f"redline-monitor ready: {', '.join(f'{n}={p}' for n, p in targets)}", flush=True)
        period, start, tick = 1e9 / rate, time.monotonic_ns(), 1
        detail_every = max(1, round(rate * DETAIL_S))
        while not stop.wait(max(0.0, (start + tick * period - time.monotonic_ns()) / 1e9)):
            _sample_all(samplers, host, out, detail=tick % detail_every == 1 % detail_every)
            if mine:
                _sample_own(mine, out)
            tick += 1
    for sampler in samplers:
        sampler.close()
    for own_sampler in mine:
        own_sampler.close()
    if host is not None:
        host.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Redline's process monitor")
    parser.add_argument("--rate", type=float, default=10.0, help="samples per second")
    parser.add_argument("--no-host", action="store_true", help="do not sample the host")
    parser.add_argument(
        "--own",
        type=int,
        action="append",
        default=None,
        metavar="PID",
        help="a process of Redline's own run (repeatable; the monitor adds itself)",
    )
    parser.add_argument("targets", nargs="+", help="NAME=PID of each process to sample")
    args = parser.parse_args(argv)
    stop = threading.Event()
    set_on_signals(stop, signal.SIGTERM, signal.SIGINT)
    run(_targets(args.targets), args.rate, stop, with_host=not args.no_host, own=args.own)
    return 0


if __name__ == "__main__":
    sys.exit(main())
