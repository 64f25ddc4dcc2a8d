"""Redline's test SDK: what a performance test imports.

A test module defines `TestCase` objects at its top level. A test case has phases; a phase is a
named tree of actions; a parameter provider such as `Cartesian` yields the parameter sets each
phase runs for, with the component kept running throughout::

    from redline.testing import Cartesian, FixedRate, Param, Phase, Publish, TestCase

    load = TestCase(
        "load",
        phases=[Phase("steady", FixedRate(Param("rate"), 2.0, Publish("demo/in", b"hello")))],
        params=Cartesian(rate=[10, 100]),
    )

Write your own action by subclassing `Action` and implementing ``run(ctx)``; use `resolve` on
arguments that may be plain values or actions. ``docs/writing-tests.md`` describes every action.
"""

from redline.testing.actions import Action, Param, Sequence, Static, resolve
from redline.testing.cases import (
    Cartesian,
    ParameterProvider,
    ParameterSet,
    Phase,
    Table,
    TestCase,
    ValidationError,
    validate_cases,
)
from redline.testing.context import Context, Link
from redline.testing.flow import Loop, Parallel, WithBackground
from redline.testing.messages import Filler, Message, Payload, Repeated
from redline.testing.metrics import Tally
from redline.testing.middleware import Publish, Query
from redline.testing.receive import Listen, WaitFor
from redline.testing.replay import Replay
from redline.testing.signals import Stop
from redline.testing.timing import FixedRate, LimitedTime, Sleep

__all__ = [
    "Action",
    "Cartesian",
    "Context",
    "Filler",
    "FixedRate",
    "LimitedTime",
    "Link",
    "Listen",
    "Loop",
    "Message",
    "Parallel",
    "Param",
    "ParameterProvider",
    "ParameterSet",
    "Payload",
    "Phase",
    "Publish",
    "Query",
    "Repeated",
    "Replay",
    "Sequence",
    "Sleep",
    "Static",
    "Stop",
    "Table",
    "Tally",
    "TestCase",
    "ValidationError",
    "WaitFor",
    "WithBackground",
    "resolve",
    "validate_cases",
]
