"""What the monitor samples: a component's whole process tree, and the host.

A component may fork workers, so its counters are those of its process and every descendant,
summed, with ``processes`` counting them. The tree is re-scanned every `RESCAN_NS`; a PID seen
again with another start time is a new process (PID reuse), never the old one continued.
"""

from __future__ import annotations

import hashlib
import os
import time

from redline.agent.procstat import ProcessSampler, WindowRate, pread, start_time

RESCAN_NS = 1_000_000_000

#: The host counter of the host's speed at the time: the monitor thread's CPU time, in µs, for a
#: fixed piece of work (`reference_work`) done at every sample. A component's CPU per unit of
#: work divided by it (`redline.recording.driver.CPU_REFS_PER_OP`) is steadier than the CPU
#: alone: on the 2-core VM one execution's CPU per operation moved with the host's speed
#: (docs/detection.md, "host-speed reference").
REFERENCE = "reference_us"
_REFERENCE_DATA = bytes(range(256)) * 256  # 64 KiB
_REFERENCE_LOOP = 3000


def reference_work() -> int:
    """A fixed piece of work (~0.35 ms on the 2-core VM): SHA-256 of 64 KiB, as compiled code
    does, and an integer loop, as the interpreter does; its result, so nothing is skipped."""
    acc = int.from_bytes(hashlib.sha256(_REFERENCE_DATA).digest()[:4], "little")
    for i in range(_REFERENCE_LOOP):
        acc = (acc * 31 + i) & 0xFFFFFFFF
    return acc


def reference_us() -> float:
    """The CPU time the calling thread took for `reference_work`, in µs: time the thread waited
    for the CPU is not in it, only how fast the CPU ran it (its clock, its caches, a sibling
    hyperthread's load)."""
    start = time.thread_time_ns()
    reference_work()
    return round((time.thread_time_ns() - start) / 1e3, 3)


class TreeSampler:
    """A process and its descendants, sampled together; raises OSError once the root is gone."""

    def __init__(self, name: str, pid: int) -> None:
        self.name, self.pid = name, pid
        self.root = ProcessSampler(name, pid)
        self.members: dict[int, ProcessSampler] = {}
        self._next_scan = 0

    def _adopt(self, pid: int) -> ProcessSampler | None:
        known = self.members.get(pid)
        try:
            if known is not None and known.start_time == start_time(pid):
                return known
            if known is not None:  # the PID was reused by another process
                self.members.pop(pid).close()
            self.members[pid] = ProcessSampler(self.name, pid)
            return self.members[pid]
        except OSError:
            return None  # exited while we looked

    def rescan(self) -> None:
        """Find the current descendants; forget those that exited."""
        seen: set[int] = set()
        frontier = [self.root]
        while frontier:
            parent = frontier.pop()
            for pid in parent.children() - seen:
                seen.add(pid)
                member = self._adopt(pid)
                if member is not None:
                    frontier.append(member)
        for pid in set(self.members) - seen:
            self.members.pop(pid).close()

    def sample(self, *, detail: bool = False) -> dict[str, float]:
        """The summed counters of the tree, with ``processes``."""
        now = time.monotonic_ns()
        if now >= self._next_scan:
            self.rescan()
            self._next_scan = now + RESCAN_NS
        values = self.root.sample(detail=detail)
        for pid, member in list(self.members.items()):
            try:
                extra = member.sample(detail=detail)
            except OSError:
                self.members.pop(pid).close()
                continue
            for counter, value in extra.items():
                values[counter] = values.get(counter, 0) + value
        values["processes"] = 1 + len(self.members)
        return values

    def close(self) -> None:
        for member in self.members.values():
            member.close()
        self.members.clear()
        self.root.close()


class HostSampler:
    """Host CPU (busy, iowait, steal; % of all CPUs), load average, and the host's speed at the
    time (`REFERENCE`)."""

    def __init__(self) -> None:
        self._stat = os.open("/proc/stat", os.O_RDONLY)
        self._loadavg = os.open("/proc/loadavg", os.O_RDONLY)
        self._rates = WindowRate()

    def sample(self) -> dict[str, float]:
        ticks = [int(v) for v in pread(self._stat, 512).split(b"\n", 1)[0].split()[1:9]]
        user, nice, system, idle, iowait, irq, softirq, steal = ticks
        values: dict[str, float] = {
            "load_1m": float(pread(self._loadavg).split()[0]),
            REFERENCE: reference_us(),
        }
        rates = self._rates.update(
            time.monotonic_ns(), (user + nice, system + irq + softirq, idle, iowait, steal)
        )
        total = sum(rates) if rates is not None else 0
        if rates is not None and total > 0:
            busy_user, busy_system, _idle, waiting, stolen = (100.0 * r / total for r in rates)
            values |= {
                "cpu_percent": round(busy_user + busy_system, 3),
                "cpu_user_percent": round(busy_user, 3),
                "cpu_system_percent": round(busy_system, 3),
                "cpu_iowait_percent": round(waiting, 3),
                "cpu_steal_percent": round(stolen, 3),
            }
        return values

    def close(self) -> None:
        os.close(self._stat)
        os.close(self._loadavg)
