"""The action tree: the base class every action derives from, and the data and flow actions.

An action is a function of the current parameter set that may return a value (the paper's
definition): ``run(ctx)`` gets a `Context` holding the parameter set, the zenoh link and the stop
signal. A parameter is itself an action, so any argument of an action may be a plain value or an
action that produces it (see `resolve`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from typing import Any

from redline.testing.context import Context


class Action:
    """Base class of every action.

    Subclasses implement `run`. Actions held in instance attributes (directly, or inside a list,
    tuple or dict) are found by `children`, so `params_used` and validation see through custom
    actions without extra code::

        class Scaled(Action):
            def __init__(self, value: Action, factor: float) -> None:
                self.value, self.factor = value, factor

            def run(self, ctx: Context) -> float:
                return resolve(self.value, ctx) * self.factor
    """

    def run(self, ctx: Context) -> Any:
        """Perform the action for the parameter set in ``ctx``; may return a value."""
        raise NotImplementedError(f"{type(self).__name__} must implement run(ctx)")

    def children(self) -> Iterator[Action]:
        """The actions this action may run or resolve (found in its attributes by default)."""
        for value in vars(self).values():
            yield from _actions_in(value)

    #: True when one run costs about a zenoh put, so loops may check their stop signal only
    #: every few dozen runs instead of every run.
    cheap = False

    def compile(self, ctx: Context) -> Callable[[], Any]:
        """A function doing one `run` for this parameter set, for loops that run it many times.

        By default it simply calls ``run(ctx)``; an action may return something faster that
        prepares once what stays the same within the parameter set (see `Publish`). A loop calls
        `ran` with the number of runs once it is done, for steps that count in bulk.
        """
        return functools.partial(self.run, ctx)

    def problems(self) -> list[str]:
        """What is wrong with this action itself, found before the run (e.g. a malformed key
        expression); the runner names the case and phase. Children are checked on their own."""
        return []

    def missing(self) -> list[str]:
        """Files this action needs that are not there (a recording to replay), found after the
        cases to run were chosen: a file of a case not chosen is no reason to refuse the run."""
        return []

    def walk(self) -> Iterator[Action]:
        """This action and every action in its tree."""
        yield self
        for child in self.children():
            yield from child.walk()

    def params_used(self) -> set[str]:
        """The names of every `Param` in this action's tree."""
        names: set[str] = set()
        for child in self.children():
            names |= child.params_used()
        return names

    def __repr__(self) -> str:
        fields = ", ".join(f"{key}={value!r}" for key, value in vars(self).items())
        return f"{type(self).__name__}({fields})"


def _actions_in(value: Any) -> Iterator[Action]:
    if isinstance(value, Action):
        yield value
    elif isinstance(value, (list, tuple)):
        for item in value:
            yield from _actions_in(item)
    elif isinstance(value, dict):
        for item in value.values():
            yield from _actions_in(item)


def ran(step: Callable[[], Any], runs: int) -> None:
    """Tell a compiled step how many times it ran, when it counts in bulk (see `Publish`)."""
    counted = getattr(step, "ran", None)
    if counted is not None and runs:
        counted(runs)


def resolve(value: Any, ctx: Context) -> Any:
    """The value of an action argument: run it when it is an action, else take it as it is."""
    return value.run(ctx) if isinstance(value, Action) else value


class Param(Action):
    """The value of parameter ``name`` in the current parameter set (the paper's Parameter).

    The runner checks before anything starts that every parameter set provides it.
    """

    def __init__(self, name: str) -> None:
        self.name = name

    def run(self, ctx: Context) -> Any:
        return ctx.param(self.name)

    def params_used(self) -> set[str]:
        return {self.name}

    def __repr__(self) -> str:
        return f"Param({self.name!r})"


class Static(Action):
    """A value that is the same for every parameter set (the paper's StaticData)."""

    def __init__(self, value: Any) -> None:
        self.value = value

    def run(self, ctx: Context) -> Any:
        return self.value


class Sequence(Action):
    """Run actions one after the other; returns the list of their results.

    Stops early (returning the results so far) when the run is stopped.
    """

    def __init__(self, *actions: Action) -> None:
        for action in actions:
            if not isinstance(action, Action):
                raise TypeError(f"Sequence takes actions, got {action!r}")
        self.actions = actions

    def run(self, ctx: Context) -> list[Any]:
        results: list[Any] = []
        for action in self.actions:
            if ctx.stopped:
                break
            results.append(action.run(ctx))
        return results
