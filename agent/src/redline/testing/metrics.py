"""Driver-side metrics that many action runs add to, summarized once per segment.

A `Tally` collects durations (round trips, waits) and named counts (timeouts, errors) from every
run of one action on one key within a segment, from any thread. The runner publishes each tally's
summary on ``@redline/driver/<case>/<phase>`` when the segment ends (`Context.flush_metrics`).
"""

from __future__ import annotations

import math
import threading
from collections import Counter
from typing import Any


def quantile(sorted_values: list[int], q: float) -> int:
    """Nearest-rank quantile of an ascending list (0 for an empty one)."""
    if not sorted_values:
        return 0
    rank = max(1, math.ceil(q * len(sorted_values)))
    return sorted_values[min(rank, len(sorted_values)) - 1]


def latency_summary(values_ns: list[int], prefix: str) -> dict[str, float]:
    """p50/p90/p99/max of nanosecond durations in microseconds: ``<prefix>_p50_us``..."""
    ordered = sorted(values_ns)
    summary = {f"{prefix}_p{int(q * 100)}_us": quantile(ordered, q) / 1e3 for q in (0.5, 0.9, 0.99)}
    summary[f"{prefix}_max_us"] = (ordered[-1] if ordered else 0) / 1e3
    return summary


class Tally:
    """Durations and counts of one action on one key; thread-safe."""

    def __init__(self, action: str, key: str, measure: str, path: str = "") -> None:
        self.action, self.key, self.measure, self.path = action, key, measure, path
        self._lock = threading.Lock()
        self._values: list[int] = []
        self._counts: Counter[str] = Counter()

    def add(self, duration_ns: int) -> None:
        """One measured duration (e.g. a round trip)."""
        with self._lock:
            self._values.append(duration_ns)

    def count(self, name: str, n: int = 1) -> None:
        """Add ``n`` to the named count (e.g. ``timeouts``; 0 records it as counted)."""
        with self._lock:
            self._counts[name] += n

    def checked(self, ok: bool, name: str = "errors", of: str = "queries") -> None:
        """One reply checked: counted (``of``), and counted as ``name`` when it is not ``ok``.
        A run whose every reply was right records 0 of them, so a revision that starts getting
        them wrong is judged as a rate out of ``of`` (`redline.recording.driver`): a count only
        ever added to when it happens is missing where it did not, and one with nothing to be
        out of cannot be rated, so neither was judged (a sixth trial's 120 wrong replies of
        120 went unmentioned)."""
        with self._lock:
            self._counts[of] += 1
            self._counts[name] += not ok

    def summary(self) -> dict[str, Any]:
        """The message published for this tally."""
        with self._lock:
            values, counts = list(self._values), dict(self._counts)
        return {
            "action": self.action,
            "path": self.path or self.action,
            "key": self.key,
            "count": len(values),
            **counts,
            # none measured (a tally of counts only): no "p50 0 µs", charted as a measurement
            **(latency_summary(values, self.measure) if values else {}),
        }
