"""Choosing what a run executes: ``--only CASE`` and ``--param name=value`` overrides, and a
confirmation run's parameter sets."""

from __future__ import annotations

import json
from collections.abc import Collection, Iterator, Mapping, Sequence
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


class Through:
    """A case's parameter sets up to and including the one whose canonical text is ``last``."""

    def __init__(self, base: TestCase, last: str) -> None:
        self.base = base
        self.last = last

    def __iter__(self) -> Iterator[ParameterSet]:
        for params in self.base.parameter_sets():
            yield params
            if canonical_params(params) == self.last:
                return

    def __repr__(self) -> str:
        return f"Through({self.base.params!r}, {self.last!r})"


class Only:
    """A case's parameter sets whose canonical texts are among ``idents``, in the case's order."""

    def __init__(self, base: TestCase, idents: Collection[str]) -> None:
        self.base = base
        self.idents = frozenset(idents)

    def __iter__(self) -> Iterator[ParameterSet]:
        for params in self.base.parameter_sets():
            if canonical_params(params) in self.idents:
                yield params

    def __repr__(self) -> str:
        return f"Only({self.base.params!r}, {sorted(self.idents)!r})"


def choose_sets(
    cases: Sequence[TestCase], sets: Mapping[str, Collection[str]], alone: bool = False
) -> list[TestCase]:
    """The run as far as the last of the named parameter sets (per case, canonical JSON, as
    `canonical_params` writes them and series name them), in the suite's order: every case and
    set before it as it is, nothing after it (a confirmation run: the flagged sets measured
    after what ran before them in the flagged run, since what a component holds depends on
    that: a leak grows over the run). With ``alone``, the named sets only, in the suite's order
    (a confirmation run of changes in what a component does per unit of work, its CPU per
    operation or a round trip, which each set's warm-up phase settles; where a named case has no
    warm-up phase, as far as the last of them all the same). Raises
    `ValidationError` naming each named set or case the suite does not have (a confirmation
    run of a commit whose tests changed since)."""
    sets = {name: idents for name, idents in sets.items() if idents}
    known = {case.name: case for case in cases}
    problems = [
        f"parameter sets of {name!r}: no such test case in this run"
        for name in sets
        if name not in known
    ]
    for name, idents in sets.items():
        if name in known:
            have = {canonical_params(params) for params in known[name].parameter_sets()}
            problems += [
                f"test case {name!r} has no parameter set {ident}"
                for ident in sorted(idents)
                if ident not in have
            ]
    if problems:
        raise ValidationError(problems)
    if not sets:
        return list(cases)
    if alone and all(any(phase.warmup for phase in known[name].phases) for name in sets):
        return [
            TestCase(case.name, case.phases, Only(case, sets[case.name]))
            for case in cases
            if case.name in sets
        ]
    end = max(index for index, case in enumerate(cases) if case.name in sets)
    case = cases[end]
    last = [
        ident for ident in map(canonical_params, case.parameter_sets()) if ident in sets[case.name]
    ]
    return [*cases[:end], TestCase(case.name, case.phases, Through(case, last[-1]))]


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
