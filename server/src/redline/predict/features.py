"""Features of a component's communication: per key and direction (received by the component, or
sent by it), the count of samples and their payload bytes (sum, mean, max) over sliding windows of
several lengths ending at each time step (Wienke & Wrede, Section 6.1).

One function, `extract`, turns (key, time, size) events into feature rows at given times. Training
calls it on a recording's events; `redline watch` on the events a live zenoh subscriber has seen in
the longest window. The same code on the same events gives the same vectors.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

#: window lengths in seconds: the rates of the last second to the load of the last ten
WINDOWS = (1.0, 2.0, 5.0, 10.0)
STATS = ("count", "bytes_sum", "bytes_mean", "bytes_max")
IN, OUT = "in", "out"  # received by the component, sent by it
NS = 1_000_000_000

#: one sample on the network: key expression, time in ns, payload bytes
Event = tuple[str, int, int]


@dataclass(frozen=True)
class FeatureSpec:
    """What the features are: the (key, direction) channels a model knows, in order, and the
    window lengths; stored with a model so that watching extracts what training did."""

    channels: tuple[tuple[str, str], ...]
    windows: tuple[float, ...] = WINDOWS

    @property
    def keys(self) -> dict[str, str]:
        return dict(self.channels)

    def names(self) -> list[str]:
        return [
            f"{direction}:{key}:{window:g}s:{stat}"
            for key, direction in self.channels
            for window in self.windows
            for stat in STATS
        ]

    def to_dict(self) -> dict[str, list]:
        return {"channels": [list(c) for c in self.channels], "windows": list(self.windows)}

    @classmethod
    def from_dict(cls, data: dict[str, list]) -> FeatureSpec:
        return cls(
            tuple((str(k), str(d)) for k, d in data["channels"]),
            tuple(float(w) for w in data["windows"]),
        )


def _range_max(values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """max(values[lo:hi]) for each pair, 0 where the range is empty (a sparse table)."""
    out = np.zeros(len(lo))
    if not len(values):
        return out
    table = [values.astype(float)]
    while 2 ** len(table) <= len(values):
        half = 2 ** (len(table) - 1)
        previous = table[-1]
        table.append(np.maximum(previous[:-half], previous[half:]))
    width = hi - lo
    some = width > 0
    level = np.zeros(len(lo), dtype=int)
    level[some] = np.floor(np.log2(width[some])).astype(int)
    for k in np.unique(level[some]):
        rows = some & (level == k)
        span = 2**k
        out[rows] = np.maximum(table[k][lo[rows]], table[k][hi[rows] - span])
    return out


def extract(events: Iterable[Event], times_ns: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """One row per time in ``times_ns``: for each channel of ``spec``, window and statistic, what
    its samples in (t - window, t] came to. Keys the spec does not know are ignored (`unseen`
    names them)."""
    times_ns = np.asarray(times_ns, dtype=np.int64)
    by_key: dict[str, list[tuple[int, int]]] = {key: [] for key, _ in spec.channels}
    for key, stamp, size in events:
        if key in by_key:
            by_key[key].append((stamp, size))
    columns = []
    for key, _ in spec.channels:
        found = sorted(by_key[key])
        stamps = np.array([s for s, _ in found], dtype=np.int64)
        sizes = np.array([b for _, b in found], dtype=float)
        totals = np.concatenate(([0.0], np.cumsum(sizes)))
        hi = np.searchsorted(stamps, times_ns, side="right")
        for window in spec.windows:
            lo = np.searchsorted(stamps, times_ns - int(window * NS), side="right")
            count = (hi - lo).astype(float)
            total = totals[hi] - totals[lo]
            mean = np.divide(total, count, out=np.zeros_like(total), where=count > 0)
            columns += [count, total, mean, _range_max(sizes, lo, hi)]
    if not columns:
        return np.zeros((len(times_ns), 0))
    return np.column_stack(columns)


def unseen(events: Iterable[Event], spec: FeatureSpec) -> set[str]:
    """The keys among ``events`` that ``spec`` does not know (a model ignores them)."""
    known = spec.keys
    return {key for key, _, _ in events if key not in known}


def spec_for(
    events: Sequence[Event], received: Iterable[str], windows: Sequence[float] = WINDOWS
) -> FeatureSpec:
    """The channels of ``events``, sorted: ``received`` keys (those the test driver sent to the
    component) in, every other key out."""
    inbound = set(received)
    keys = sorted({key for key, _, _ in events})
    return FeatureSpec(tuple((k, IN if k in inbound else OUT) for k in keys), tuple(windows))
