"""Absolute effect-size floors per counter: the smallest change of a mean worth reporting.

A relative floor alone misjudges small values: 0.4 percentage points of CPU on a component that
uses 4 % of a core is a 10 % change, and exactly the size of run-to-run noise on a shared host
(measured on the example component, see docs/detection.md). A change must clear both floors.
The values are the resolution below which a developer could not act on a change: one
percentage point of a core, one MiB of memory, one thread, process or file descriptor.
"""

from __future__ import annotations

MIB = 1024.0 * 1024.0

#: (counter name suffix or exact name, floor) — the first match wins.
FLOORS: tuple[tuple[str, float], ...] = (
    ("_percent", 1.0),  # percentage points of one core
    ("_bytes", MIB),
    ("threads", 1.0),
    ("processes", 1.0),
    ("fds", 1.0),
    ("_per_s", 10.0),  # context switches and other rates, per second
)


def absolute_floor(counter: str) -> float:
    """The absolute floor of ``counter`` (0 for counters this table does not know)."""
    for suffix, floor in FLOORS:
        if counter.endswith(suffix):
            return floor
    return 0.0
