"""Which cores each part of a run may use (Linux ``sched_setaffinity``), from the suite file::

    [affinity]              # optional; unset parts may use every core
    components = [1]        # every [[component]] and [[fixture]] (a process may set `cpus`)
    driver = [0]            # the runner: the test driver and the run's zenoh router
    recorder = [0]
    monitor = [0]

Keeping the component apart from Redline's own processes removes one source of noise between
executions (the driver and recorder competing for the component's core); whether it helps on a
given host is measured with `redline calibrate` (docs/detection.md). The affinity in force is
recorded in the run's metadata (``affinity``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from typing import Any

PARTS = ("components", "driver", "recorder", "monitor")
#: the cores this process could use when it started (before a run pinned its own threads)
AVAILABLE = frozenset(os.sched_getaffinity(0))


class AffinityError(ValueError):
    """An affinity that cannot be used (a core this host does not offer, say)."""


@dataclass(frozen=True)
class Affinity:
    """The cores of each part (an empty tuple: every core)."""

    cores: Mapping[str, tuple[int, ...]] = field(default_factory=dict)

    def of(self, part: str) -> tuple[int, ...]:
        return self.cores.get(part, ())

    def describe(self) -> str:
        """As recorded in the run's metadata: JSON of the parts pinned, or ``none``."""
        pinned = {part: list(cores) for part, cores in self.cores.items() if cores}
        return json.dumps(pinned, sort_keys=True) if pinned else "none"


def parse_cores(value: Any, where: str) -> tuple[int, ...]:
    """A list of core numbers from the suite file; ValueError saying what is wrong."""
    if (
        not isinstance(value, list)
        or not value
        or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value)
    ):
        raise ValueError(
            f"{where} must be a non-empty list of core numbers (0, 1, ...), got {value!r}"
        )
    return tuple(sorted(set(value)))


def parse_affinity(table: Any) -> Affinity:
    """The suite's ``[affinity]`` table; ValueError naming the field at fault."""
    if table is None:
        return Affinity()
    if not isinstance(table, dict):
        raise ValueError("'affinity' must be a table ([affinity])")
    unknown = sorted(set(table) - set(PARTS))
    if unknown:
        raise ValueError(f"[affinity]: unknown part {unknown[0]!r}; known: {', '.join(PARTS)}")
    return Affinity(
        {part: parse_cores(value, f"[affinity] {part}") for part, value in table.items()}
    )


def check_available(cores: Sequence[int]) -> set[int]:
    """``cores`` as a set, if this process may run on every one of them."""
    available = AVAILABLE
    missing = sorted(set(cores) - available)
    if missing:
        raise AffinityError(
            f"core(s) {missing} are not available on this host (available: "
            f"{sorted(available)}); change [affinity] in the suite file"
        )
    return set(cores)


def preexec(cores: Sequence[int]) -> Any:
    """A ``preexec_fn`` pinning a child process to ``cores`` (None: no pinning)."""
    if not cores:
        return None
    wanted = check_available(cores)
    return lambda: os.sched_setaffinity(0, wanted)


def _threads() -> list[int]:
    return [int(tid) for tid in os.listdir("/proc/self/task")]


@contextmanager
def pinned(cores: Sequence[int]) -> Iterator[None]:
    """Every thread of this process on ``cores`` while inside (threads started meanwhile
    inherit it); each thread's own affinity back afterwards."""
    if not cores:
        yield
        return
    wanted = check_available(cores)
    before = {tid: os.sched_getaffinity(tid) for tid in _threads()}
    for tid in before:
        os.sched_setaffinity(tid, wanted)
    try:
        yield
    finally:
        for tid, was in before.items():
            with suppress(OSError):  # the thread has ended
                os.sched_setaffinity(tid, was)
