"""Timing actions: run a child action at a fixed rate for a given time."""

from __future__ import annotations

import math
import time
from typing import Any

from redline.testing.actions import Action, resolve
from redline.testing.context import Context


def quantile(sorted_values: list[int], q: float) -> int:
    """Nearest-rank quantile of an ascending list (0 for an empty one)."""
    if not sorted_values:
        return 0
    rank = max(1, math.ceil(q * len(sorted_values)))
    return sorted_values[min(rank, len(sorted_values)) - 1]


def _positive(name: str, value: Any) -> float:
    number = float(value)
    if not number > 0:
        raise ValueError(f"FixedRate {name} must be positive, got {value!r}")
    return number


class FixedRate(Action):
    """Run ``action`` ``rate`` times per second for ``duration`` seconds (the paper's FixedRate).

    ``rate`` and ``duration`` are numbers or actions such as ``Param("rate")``. Each iteration has
    an absolute deadline (start + i / rate), so the rate does not drift; when the child is slower
    than the period the schedule catches up and the lateness shows it. Reports, as driver
    metrics: target and achieved rate, iterations, and lateness p50/p99/max in microseconds.
    Returns the number of iterations run.
    """

    def __init__(self, rate: float | Action, duration: float | Action, action: Action) -> None:
        if not isinstance(action, Action):
            raise TypeError(f"FixedRate runs an action, got {action!r}")
        self.rate = rate
        self.duration = duration
        self.action = action

    def run(self, ctx: Context) -> int:
        rate = _positive("rate", resolve(self.rate, ctx))
        duration = _positive("duration", resolve(self.duration, ctx))
        period_ns = 1e9 / rate
        start = time.perf_counter_ns()
        end = start + int(duration * 1e9)
        lateness: list[int] = []
        deadline = start
        while deadline < end and ctx.sleep_until(deadline):
            lateness.append(time.perf_counter_ns() - deadline)
            self.action.run(ctx)
            deadline = start + int(len(lateness) * period_ns)
        ctx.sleep_until(end)
        elapsed = (time.perf_counter_ns() - start) / 1e9
        lateness.sort()
        ctx.report({
            "action": "FixedRate", "rate_target": rate, "duration_s": round(elapsed, 6),
            "iterations": len(lateness), "rate_achieved": len(lateness) / elapsed,
            "lateness_p50_us": quantile(lateness, 0.5) / 1e3,
            "lateness_p99_us": quantile(lateness, 0.99) / 1e3,
            "lateness_max_us": (lateness[-1] if lateness else 0) / 1e3,
            "interrupted": ctx.stopped,
        })
        return len(lateness)
