"""Choosing what a run executes: ``--only CASE`` and ``--param name=value`` overrides."""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from redline.recording.format import canonical_params
from redline.testing import ParameterSet, TestCase, ValidationError


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``["rate=40", "mode=fast"]`` → ``{"rate": 40, "mode": "fast"}`` (JSON values, else text)."""
    overrides: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ValidationError([f"--param {item!r}: expected NAME=VALUE"])
        try:
            overrides[name.strip()] = json.loads(text)
        except ValueError:
            overrides[name.strip()] = text
    return overrides


class Overridden:
    """A case's parameter sets with some values replaced; sets made equal by it are run once."""

    def __init__(self, base: TestCase, overrides: Mapping[str, Any]) -> None:
        self.base = base
        self.overrides = dict(overrides)

    def __iter__(self) -> Iterator[ParameterSet]:
        seen: set[str] = set()
        for params in self.base.parameter_sets():
            changed = ParameterSet({**params, **self.overrides})
            ident = canonical_params(changed)
            if ident not in seen:
                seen.add(ident)
                yield changed

    def __repr__(self) -> str:
        return f"Overridden({self.base.params!r}, {self.overrides!r})"


def _names_of(case: TestCase) -> set[str]:
    names = {name for phase in case.phases for name in phase.action.params_used()}
    for params in case.parameter_sets():
        names |= set(params)
    return names


def select_cases(
    cases: Sequence[TestCase], only: Sequence[str] = (), overrides: Mapping[str, Any] | None = None
) -> list[TestCase]:
    """The cases named by ``only`` (all when empty), with ``overrides`` applied to every set.

    Raises `ValidationError` naming every unknown case and every parameter no chosen case uses.
    """
    known = [case.name for case in cases]
    problems = [
        f"--only {name!r}: no such test case (the suite has: {', '.join(known)})"
        for name in only
        if name not in known
    ]
    chosen = [case for case in cases if not only or case.name in only]
    used = set().union(*(_names_of(case) for case in chosen)) if chosen else set()
    problems += [
        f"--param {name!r}: no chosen test case uses this parameter "
        f"(they use: {', '.join(sorted(used)) or 'none'})"
        for name in (overrides or {})
        if name not in used
    ]
    if problems:
        raise ValidationError(problems)
    if not overrides:
        return chosen
    selected = []
    for case in chosen:  # a case is only given the overrides of parameters it uses
        own = {name: value for name, value in overrides.items() if name in _names_of(case)}
        selected.append(TestCase(case.name, case.phases, Overridden(case, own)) if own else case)
    return selected
