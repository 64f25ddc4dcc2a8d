"""Absolute effect-size floors per counter: the smallest change of a mean worth reporting.

A relative floor alone misjudges small values: 0.4 percentage points of CPU on a component that
uses 4 % of a core is a 10 % change, and exactly the size of run-to-run noise on a shared host
(measured on the example component, see docs/detection.md). A change must clear both floors.
The values are the resolution below which a developer could not act on a change: one
percentage point of a core, one MiB of memory, one thread, process or file descriptor; for the
driver's metrics, 20 µs of a round trip or of lateness (a tenth of a loopback zenoh round trip,
~200 µs; FIELD-NOTES) and one message per second of a rate. The CPU per unit of work in
units of the host's reference work (``cpu_refs_per_op``) is no count of microseconds: one
reference took 280-430 µs on these VMs, so the microseconds' floor of 1 would ask a change of
at least one reference per operation (a component at 8 references an operation could not be
flagged below +12 %, one at 1.2, as light as the example's 2-legs sets, below +80 %); its floor
is a hundredth of a reference, a few microseconds.
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
    ("cpu_refs_per_op", 0.01),  # the same in units of the host's reference work (280-430 µs)
    ("_per_op", 1.0),  # a component's CPU microseconds per unit of work the driver delivered
    ("_us", 20.0),  # the driver's round trips, waits and lateness
    ("rate_achieved", 1.0),  # FixedRate's iterations per second
    (":rate", 1.0),  # Listen's samples per second
)


def absolute_floor(counter: str) -> float:
    """The absolute floor of ``counter`` (0 for counters this table does not know)."""
    for suffix, floor in FLOORS:
        if counter.endswith(suffix):
            return floor
    return 0.0
