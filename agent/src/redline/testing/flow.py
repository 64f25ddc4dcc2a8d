"""Flow actions: Loop, Parallel and WithBackground (Sequence lives in actions.py)."""

from __future__ import annotations

import threading
from typing import Any

from redline.testing.actions import Action, ran, resolve
from redline.testing.context import Context

CHEAP_BATCH = 64  # cheap children (a put, ~1.5 us): check the stop signal every 64 runs


def _check_actions(kind: str, actions: tuple[Any, ...]) -> tuple[Action, ...]:
    for action in actions:
        if not isinstance(action, Action):
            raise TypeError(f"{kind} takes actions, got {action!r}")
    return actions


class Loop(Action):
    """Run ``action`` ``times`` times, or until interrupted when ``times`` is None (paper's Loop).

    ``times`` is a number or an action such as ``Param("count")``. An endless loop belongs inside
    `LimitedTime` or as the background of `WithBackground`. Returns the number of iterations run.
    """

    def __init__(self, action: Action, times: int | Action | None = None) -> None:
        _check_actions("Loop", (action,))
        self.action = action
        self.times = times

    def run(self, ctx: Context) -> int:
        times = resolve(self.times, ctx)
        limit = None if times is None else int(times)
        step = self.action.compile(ctx)
        batch = CHEAP_BATCH if self.action.cheap else 1
        done = 0
        try:
            while (limit is None or done < limit) and not ctx.stopped:
                runs = batch if limit is None else min(batch, limit - done)
                for _ in range(runs):
                    step()
                done += runs
        finally:
            ran(step, done)
        return done


class _Worker(threading.Thread):
    """Runs one action on a context, keeping its result or its exception."""

    def __init__(self, action: Action, ctx: Context, name: str) -> None:
        super().__init__(name=name, daemon=True)
        self.action, self.ctx = action, ctx
        self.result: Any = None
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self.result = self.action.run(self.ctx)
        except BaseException as exc:  # handed to the parent thread, which raises it
            self.error = exc
            self.ctx.stop.set()  # a failed branch stops its siblings


def _join(workers: list[_Worker]) -> list[Any]:
    for worker in workers:
        worker.join()
    for worker in workers:
        if worker.error is not None:
            raise worker.error
    return [worker.result for worker in workers]


class Parallel(Action):
    """Run actions at the same time, each on its own thread; returns their results in order.

    When one fails the others are stopped and its exception is raised. Threads share the GIL: use
    it to overlap waiting (publishing on two keys, a query while publishing), not to add CPU.
    """

    def __init__(self, *actions: Action) -> None:
        self.actions = _check_actions("Parallel", actions)

    def run(self, ctx: Context) -> list[Any]:
        shared = ctx.child()
        workers = [_Worker(a, shared, f"parallel-{i}") for i, a in enumerate(self.actions)]
        for worker in workers:
            worker.start()
        return _join(workers)


class WithBackground(Action):
    """Run ``main`` while ``background`` actions run beside it; they are interrupted when it ends.

    The paper's WithBackground: e.g. publish poses in a loop while the main action measures leg
    messages. Returns the result of ``main``; an exception in a background action is raised once
    ``main`` is done.
    """

    def __init__(self, main: Action, *background: Action) -> None:
        _check_actions("WithBackground", (main, *background))
        if not background:
            raise TypeError("WithBackground needs at least one background action")
        self.main = main
        self.background = background

    def run(self, ctx: Context) -> Any:
        behind = ctx.child()
        workers = [_Worker(a, behind, f"background-{i}") for i, a in enumerate(self.background)]
        for worker in workers:
            worker.start()
        try:
            result = self.main.run(ctx)
        finally:
            behind.stop.set()
            for worker in workers:
                worker.join()
        _join(workers)  # raises a background failure, now that main has succeeded
        return result
