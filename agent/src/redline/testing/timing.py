"""Timing actions: Sleep, LimitedTime, and FixedRate (a child action at a fixed rate)."""

from __future__ import annotations

import time
from typing import Any

from redline.testing.actions import Action, ran, resolve
from redline.testing.context import Context
from redline.testing.metrics import quantile

__all__ = ["FixedRate", "LimitedTime", "Sleep", "quantile"]


def _positive(name: str, value: Any, action: str = "FixedRate") -> float:
    number = float(value)
    if not number > 0:
        raise ValueError(f"{action} {name} must be positive, got {value!r}")
    return number


class Sleep(Action):
    """Wait ``seconds`` (a number or an action such as ``Param("pause")``); ends early when stopped.

    Returns True when the full time passed, False when the run or a parent action stopped it.
    """

    def __init__(self, seconds: float | Action) -> None:
        self.seconds = seconds

    def run(self, ctx: Context) -> bool:
        seconds = float(resolve(self.seconds, ctx))
        if seconds < 0:
            raise ValueError(f"Sleep seconds must not be negative, got {seconds!r}")
        return ctx.sleep_until(time.perf_counter_ns() + int(seconds * 1e9))


class LimitedTime(Action):
    """Run ``action`` for at most ``seconds``, then interrupt it (the paper's LimitedTime).

    The child sees its stop signal set at the limit: `Loop`, `FixedRate`, `Sleep`, `WaitFor` and
    `Replay` end then; a custom action must watch ``ctx.stopped`` to be interruptible. Returns the
    child's result. ``LimitedTime(5, Loop(Publish(...)))`` publishes as fast as it can for 5 s.
    """

    def __init__(self, seconds: float | Action, action: Action) -> None:
        if not isinstance(action, Action):
            raise TypeError(f"LimitedTime runs an action, got {action!r}")
        self.seconds = seconds
        self.action = action

    def run(self, ctx: Context) -> Any:
        seconds = _positive("seconds", resolve(self.seconds, ctx), "LimitedTime")
        return self.action.run(ctx.child(time.perf_counter_ns() + int(seconds * 1e9)))


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
        step = self.action.compile(ctx)
        while deadline < end and ctx.sleep_until(deadline):
            lateness.append(time.perf_counter_ns() - deadline)
            step()
            deadline = start + int(len(lateness) * period_ns)
        ran(step, len(lateness))
        ctx.sleep_until(end)
        elapsed = (time.perf_counter_ns() - start) / 1e9
        lateness.sort()
        ctx.report(
            action=self,
            metrics={
                "action": "FixedRate",
                "rate_target": rate,
                "duration_s": round(elapsed, 6),
                "iterations": len(lateness),
                "rate_achieved": len(lateness) / elapsed,
                "lateness_p50_us": quantile(lateness, 0.5) / 1e3,
                "lateness_p99_us": quantile(lateness, 0.99) / 1e3,
                "lateness_max_us": (lateness[-1] if lateness else 0) / 1e3,
                "interrupted": ctx.stopped,
            },
        )
        return len(lateness)
