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
arguments that may be plain values or actions.
"""

from redline.testing.actions import Action, Param, Sequence, Static, resolve
from redline.testing.cases import (
    Cartesian,
    ParameterProvider,
    ParameterSet,
    Phase,
    TestCase,
    ValidationError,
    validate_cases,
)
from redline.testing.context import Context, Link
from redline.testing.middleware import Publish
from redline.testing.timing import FixedRate

__all__ = [
    "Action",
    "Cartesian",
    "Context",
    "FixedRate",
    "Link",
    "Param",
    "ParameterProvider",
    "ParameterSet",
    "Phase",
    "Publish",
    "Sequence",
    "Static",
    "TestCase",
    "ValidationError",
    "resolve",
    "validate_cases",
]
