"""Reading one process's counters from /proc, cheaply: kept-open files read with ``os.pread``.

Measured on the 2-core VM (FIELD-NOTES): a pread of a /proc file costs ~4 µs, psutil's oneshot
of six counters ~72 µs, and ``smaps_rollup`` (USS/PSS) ~1 ms, so the latter is read at ~1 Hz.
Context switches are summed over every thread: ``/proc/PID/status`` covers only the main one.
"""

from __future__ import annotations

import collections
import os
import time

PAGE = os.sysconf("SC_PAGE_SIZE")
TICKS = os.sysconf("SC_CLK_TCK")
WINDOW_NS = 500_000_000  # utime/stime tick at 10 ms: rates over >= 0.5 s windows (FIELD-NOTES)
VOLUNTARY = b"\nvoluntary_ctxt_switches:"
INVOLUNTARY = b"\nnonvoluntary_ctxt_switches:"


def pread(fd: int, size: int = 4096) -> bytes:
    return os.pread(fd, size, 0)


def open_optional(path: str) -> int | None:
    """A kept-open /proc file, or None where it cannot be read (e.g. another user's io)."""
    try:
        fd = os.open(path, os.O_RDONLY)
        pread(fd)
        return fd
    except OSError:
        return None


def stat_fields(raw: bytes) -> list[bytes]:
    """Fields of /proc/PID/stat after the command name (field 3 = index 0)."""
    return raw[raw.rindex(b")") + 2 :].split()


def start_time(pid: int) -> int:
    """The process's start time in ticks since boot: with the PID, it names one process."""
    with open(f"/proc/{pid}/stat", "rb") as stat:
        return int(stat_fields(stat.read())[19])


def _after(text: bytes, label: bytes) -> int:
    at = text.find(label)
    if at < 0:
        return 0
    start = at + len(label)
    end = text.find(b"\n", start)
    return int(text[start : end if end >= 0 else None])


class WindowRate:
    """Per-second rates of cumulative counters over a window of at least `WINDOW_NS`."""

    def __init__(self) -> None:
        self._history: collections.deque[tuple[int, tuple[float, ...]]] = collections.deque()

    def update(self, now_ns: int, values: tuple[float, ...]) -> tuple[float, ...] | None:
        self._history.append((now_ns, values))
        while len(self._history) > 2 and now_ns - self._history[1][0] >= WINDOW_NS:
            self._history.popleft()
        then, old = self._history[0]
        if now_ns == then:
            return None
        seconds = (now_ns - then) / 1e9
        return tuple((new - was) / seconds for new, was in zip(values, old, strict=True))


class _Thread:
    """Kept-open schedstat and status of one thread, with their last readings."""

    def __init__(self, root: str, tid: str) -> None:
        self.schedstat = os.open(f"{root}/task/{tid}/schedstat", os.O_RDONLY)
        try:
            self.status = os.open(f"{root}/task/{tid}/status", os.O_RDONLY)
        except OSError:
            os.close(self.schedstat)
            raise
        self.run_ns = 0  # a new thread counts from zero: its whole run time is new
        self.switches = (0, 0)

    def cpu_gained(self) -> int:
        run_ns = int(pread(self.schedstat).split(maxsplit=1)[0])
        gained, self.run_ns = run_ns - self.run_ns, run_ns
        return gained

    def switches_gained(self) -> tuple[int, int]:
        status = pread(self.status, 8192)
        now = (_after(status, VOLUNTARY), _after(status, INVOLUNTARY))
        gained = (now[0] - self.switches[0], now[1] - self.switches[1])
        self.switches = now
        return gained

    def close(self) -> None:
        os.close(self.schedstat)
        os.close(self.status)


class ProcessSampler:
    """Counters of one process (see `sample`); raises OSError once the process is gone.

    Every sample reads the run time of the known threads (kept-open schedstat files); a
    ``detail`` sample (ask for one about once a second) also re-lists the threads and reads
    what costs more: context switches, open files, USS and PSS. A thread that starts between
    two listings has its whole run time counted when it is found.
    """

    def __init__(self, name: str, pid: int) -> None:
        self.name, self.pid = name, pid
        self._root = f"/proc/{pid}"
        self._stat = os.open(f"{self._root}/stat", os.O_RDONLY)
        self.start_time = int(stat_fields(pread(self._stat))[19])
        self._statm = os.open(f"{self._root}/statm", os.O_RDONLY)
        self._io = open_optional(f"{self._root}/io")
        self._rollup = open_optional(f"{self._root}/smaps_rollup")
        self._threads: dict[str, _Thread] = {}
        self._times = WindowRate()
        self._last_ns = self._detail_ns = time.monotonic_ns()
        self._list_threads()
        self._cpu_gained()  # baseline, so the first sample covers one interval
        self._switches_gained()

    def _list_threads(self) -> None:
        tids = os.listdir(f"{self._root}/task")
        for tid in tids:
            if tid not in self._threads:
                try:
                    self._threads[tid] = _Thread(self._root, tid)
                except OSError:
                    continue  # the thread exited between listdir and open
        for tid in set(self._threads) - set(tids):
            self._threads.pop(tid).close()

    def _cpu_gained(self) -> int:
        """Run ns gained by all known threads since the last call; exited ones are dropped."""
        gained = 0
        for tid, thread in list(self._threads.items()):
            try:
                gained += thread.cpu_gained()
            except (OSError, ValueError, IndexError):
                self._threads.pop(tid).close()
        return gained

    def _switches_gained(self) -> tuple[int, int]:
        voluntary = involuntary = 0
        for thread in self._threads.values():
            try:
                more = thread.switches_gained()
            except (OSError, ValueError):
                continue
            voluntary, involuntary = voluntary + more[0], involuntary + more[1]
        return voluntary, involuntary

    def sample(self, *, detail: bool = False) -> dict[str, float]:
        """One sample; ``detail`` adds context switches, fds, USS and PSS (about 1 Hz)."""
        if detail:
            self._list_threads()
        run_ns = self._cpu_gained()
        now = time.monotonic_ns()
        interval, self._last_ns = (now - self._last_ns) / 1e9, now
        statm = pread(self._statm).split()
        values: dict[str, float] = {
            "cpu_percent": round(100.0 * run_ns / 1e9 / interval, 3) if interval > 0 else 0.0,
            "rss_bytes": int(statm[1]) * PAGE,
            "vms_bytes": int(statm[0]) * PAGE,
            "threads": len(self._threads),
        }
        fields = stat_fields(pread(self._stat))
        rates = self._times.update(now, (int(fields[11]) / TICKS, int(fields[12]) / TICKS))
        if rates is not None:
            values["cpu_user_percent"] = round(100.0 * rates[0], 3)
            values["cpu_system_percent"] = round(100.0 * rates[1], 3)
        if self._io is not None:
            io = dict(line.split(b": ") for line in pread(self._io).splitlines())
            values["io_read_bytes"] = int(io[b"rchar"])
            values["io_write_bytes"] = int(io[b"wchar"])
        if detail:
            values.update(self._detail(now))
        return values

    def _detail(self, now: int) -> dict[str, float]:
        seconds, self._detail_ns = (now - self._detail_ns) / 1e9, now
        voluntary, involuntary = self._switches_gained()
        values: dict[str, float] = {"fds": len(os.listdir(f"{self._root}/fd"))}
        if seconds > 0:
            values["ctx_voluntary_per_s"] = round(voluntary / seconds, 3)
            values["ctx_involuntary_per_s"] = round(involuntary / seconds, 3)
        if self._rollup is not None:
            values.update(_uss_pss(pread(self._rollup, 16384)))
        return values

    def children(self) -> set[int]:
        """PIDs of this process's direct children (from every thread's ``children`` file)."""
        found: set[int] = set()
        for tid in os.listdir(f"{self._root}/task"):
            try:
                with open(f"{self._root}/task/{tid}/children", "rb") as listing:
                    found.update(int(pid) for pid in listing.read().split())
            except OSError:
                continue
        return found

    def close(self) -> None:
        for thread in self._threads.values():
            thread.close()
        self._threads.clear()
        for fd in (self._stat, self._statm, self._io, self._rollup):
            if fd is not None:
                os.close(fd)


def _uss_pss(rollup: bytes) -> dict[str, float]:
    kib = {
        line.split(b":")[0]: int(line.split()[1])
        for line in rollup.splitlines()[1:]
        if line.endswith(b"kB")
    }
    private = kib.get(b"Private_Clean", 0) + kib.get(b"Private_Dirty", 0)
    return {"uss_bytes": private * 1024, "pss_bytes": kib.get(b"Pss", 0) * 1024}
