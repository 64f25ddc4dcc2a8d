"""The monitor process: samples each component process from /proc and publishes the counters.

    python -m redline.agent.monitor --rate 10 objectbuilder=1234 [name=pid ...]

Client settings for zenoh come as JSON in ``REDLINE_ZENOH``. Each sample is published as
``{"t_ns", "pid", "process", "values": {...}}`` on ``@redline/counters/<name>``. CPU comes from the
nanosecond run time of every thread (``/proc/PID/task/*/schedstat``), summed with per-thread
deltas so exiting threads never make it negative; utime ticks (10 ms) are too coarse at 10 Hz.
Files are kept open and read with ``os.pread`` (~4 µs a read, FIELD-NOTES).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time

from redline.agent.network import client_settings_from_env, open_client
from redline.recording.format import COUNTERS_PREFIX

PAGE = os.sysconf("SC_PAGE_SIZE")


def _pread(fd: int) -> bytes:
    return os.pread(fd, 4096, 0)


class ProcessSampler:
    """Counters of one process: cpu_percent, rss_bytes, threads, io_read_bytes, io_write_bytes."""

    def __init__(self, name: str, pid: int) -> None:
        self.name, self.pid = name, pid
        self._root = f"/proc/{pid}"
        self._statm = os.open(f"{self._root}/statm", os.O_RDONLY)
        self._io = _open_optional(f"{self._root}/io")
        self._threads: dict[str, tuple[int, int]] = {}  # tid -> (fd, last run time ns)
        self._last_ns = time.monotonic_ns()
        self._sample_threads()  # baseline, so the first sample covers one interval

    def _sample_threads(self) -> int:
        """Run time gained by all threads since the last call, in ns."""
        gained = 0
        tids = os.listdir(f"{self._root}/task")
        for tid in tids:
            known = self._threads.get(tid)
            try:
                fd = known[0] if known else os.open(
                    f"{self._root}/task/{tid}/schedstat", os.O_RDONLY)
                run_ns = int(_pread(fd).split(maxsplit=1)[0])
            except (OSError, ValueError, IndexError):
                continue  # the thread exited between listdir and read
            gained += run_ns - (known[1] if known else 0)
            self._threads[tid] = (fd, run_ns)
        for tid in set(self._threads) - set(tids):
            os.close(self._threads.pop(tid)[0])
        return gained

    def sample(self) -> dict[str, float]:
        """One sample; raises OSError once the process is gone."""
        gained = self._sample_threads()
        now = time.monotonic_ns()
        interval, self._last_ns = now - self._last_ns, now
        values: dict[str, float] = {
            "cpu_percent": round(100.0 * gained / interval, 3) if interval > 0 else 0.0,
            "rss_bytes": int(_pread(self._statm).split()[1]) * PAGE,
            "threads": len(self._threads),
        }
        if self._io is not None:
            fields = dict(line.split(b": ") for line in _pread(self._io).splitlines())
            values["io_read_bytes"] = int(fields[b"rchar"])
            values["io_write_bytes"] = int(fields[b"wchar"])
        return values

    def close(self) -> None:
        for fd, _ in self._threads.values():
            os.close(fd)
        self._threads.clear()
        for fd in (self._statm, self._io):
            if fd is not None:
                os.close(fd)


def _open_optional(path: str) -> int | None:
    try:
        fd = os.open(path, os.O_RDONLY)
        _pread(fd)
        return fd
    except OSError:
        return None


def _targets(specs: list[str]) -> list[tuple[str, int]]:
    targets = []
    for spec in specs:
        name, _, pid = spec.partition("=")
        if not name or not pid.isdigit():
            raise SystemExit(f"monitor: expected NAME=PID, got {spec!r}")
        targets.append((name, int(pid)))
    return targets


def run(targets: list[tuple[str, int]], rate: float, stop: threading.Event) -> None:
    """Sample every target at ``rate`` Hz on absolute deadlines until ``stop`` is set."""
    samplers = [ProcessSampler(name, pid) for name, pid in targets]
    with open_client(client_settings_from_env()) as session:
        publishers = {s.name: session.declare_publisher(COUNTERS_PREFIX + s.name) for s in samplers}
        print(f"redline-monitor ready: {', '.join(f'{n}={p}' for n, p in targets)}", flush=True)
        period, start, tick = 1e9 / rate, time.monotonic_ns(), 1
        while not stop.wait(max(0.0, (start + tick * period - time.monotonic_ns()) / 1e9)):
            tick += 1
            for sampler in list(samplers):
                try:
                    values = sampler.sample()
                except OSError:
                    print(f"redline-monitor: {sampler.name} (pid {sampler.pid}) is gone",
                          flush=True)
                    samplers.remove(sampler)
                    sampler.close()
                    continue
                publishers[sampler.name].put(json.dumps({
                    "t_ns": time.time_ns(), "pid": sampler.pid, "process": sampler.name,
                    "values": values}))
    for sampler in samplers:
        sampler.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Redline's process monitor")
    parser.add_argument("--rate", type=float, default=10.0, help="samples per second")
    parser.add_argument("targets", nargs="+", help="NAME=PID of each process to sample")
    args = parser.parse_args(argv)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    run(_targets(args.targets), args.rate, stop)
    return 0


if __name__ == "__main__":
    sys.exit(main())
