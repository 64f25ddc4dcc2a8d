"""Test cases, phases, parameter providers, and the validation that runs before anything starts."""

from __future__ import annotations

import itertools
import re
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any, Protocol

from redline.recording.format import params_name
from redline.testing.actions import Action
from redline.testing.paths import action_paths

_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")  # names become zenoh key chunks: no '/', '*', '$', '#'


def _check_name(kind: str, name: str) -> str:
    if not isinstance(name, str) or not _NAME.match(name):
        raise ValueError(f"{kind} name {name!r} must be letters, digits, '_', '.' or '-'")
    return name


class ParameterSet(dict[str, Any]):
    """One combination of parameter values, e.g. ``{"legs": 8, "rate": 40}``.

    A plain dict (so it serializes as JSON) with a printable `name`: ``legs=8,rate=40``.
    """

    @property
    def name(self) -> str:
        """The printable name of this set (``default`` when it is empty)."""
        return params_name(self)


class ParameterProvider(Protocol):
    """Anything that yields parameter sets: `Cartesian`, `Table`, or your own iterable."""

    def __iter__(self) -> Iterator[dict[str, Any]]: ...


class Cartesian:
    """Every combination of the given parameter values, in the order the names are given.

    ``Cartesian(legs=[2, 8], rate=[10, 40])`` yields ``legs=2,rate=10``, ``legs=2,rate=40``,
    ``legs=8,rate=10`` and ``legs=8,rate=40``. ``where`` keeps only the combinations it accepts
    (the paper's constraints), e.g. ``where=lambda p: p["legs"] * p["rate"] <= 200``.
    """

    def __init__(
        self, where: Callable[[ParameterSet], bool] | None = None, **values: Iterable[Any]
    ) -> None:
        if where is not None and not callable(where):
            raise TypeError(
                f"Cartesian(where=...) takes a function of the parameter set, got {where!r}"
            )
        self.where = where
        self.values: dict[str, list[Any]] = {}
        for name, options in values.items():
            if isinstance(options, (str, bytes)) or not isinstance(options, Iterable):
                raise TypeError(f"Cartesian({name}=...) takes a list of values, got {options!r}")
            self.values[name] = list(options)
            if not self.values[name]:
                raise ValueError(f"Cartesian({name}=...) has no values")

    def __iter__(self) -> Iterator[ParameterSet]:
        names = list(self.values)
        for combination in itertools.product(*self.values.values()):
            params = ParameterSet(zip(names, combination, strict=True))
            if self.where is None or self.where(params):
                yield params

    def __repr__(self) -> str:
        where = "" if self.where is None else ", where=..."
        return f"Cartesian({', '.join(f'{k}={v!r}' for k, v in self.values.items())}{where})"


class Table:
    """Parameter sets written out row by row (the paper's table provider).

    Either dicts, ``Table([{"legs": 2, "rate": 10}, {"legs": 8, "rate": 40}])``, or a header
    and tuples, ``Table(["legs", "rate"], [(2, 10), (8, 40)])``.
    """

    def __init__(self, rows: Sequence[Any], values: Sequence[Sequence[Any]] | None = None) -> None:
        if values is None:
            self.rows = [self._row(row, index) for index, row in enumerate(rows)]
            return
        header = list(rows)
        self.rows = []
        for index, row in enumerate(values):
            if len(row) != len(header):
                raise ValueError(
                    f"Table row {index + 1} has {len(row)} values for "
                    f"{len(header)} columns {header}"
                )
            self.rows.append(ParameterSet(zip(header, row, strict=True)))

    @staticmethod
    def _row(row: Any, index: int) -> ParameterSet:
        if not isinstance(row, Mapping):
            raise TypeError(
                f"Table row {index + 1} must be a dict of parameter values, got {row!r}"
            )
        return ParameterSet(row)

    def __iter__(self) -> Iterator[ParameterSet]:
        return iter([ParameterSet(row) for row in self.rows])

    def __repr__(self) -> str:
        return f"Table({len(self.rows)} rows)"


class Phase:
    """A named tree of actions, run once per parameter set of its test case.

    A ``warmup`` phase is run and recorded but left out of the analysis.
    """

    def __init__(self, name: str, action: Action, *, warmup: bool = False) -> None:
        if not isinstance(action, Action):
            raise TypeError(f"Phase {name!r} needs an action, got {action!r}")
        self.name = _check_name("phase", name)
        self.action = action
        self.warmup = warmup
        #: each action of the tree (by id) with its path, under which its metrics are recorded
        self.paths = action_paths(action)

    def __repr__(self) -> str:
        return f"Phase({self.name!r}, {self.action!r}, warmup={self.warmup})"


class TestCase:
    """Phases run in order, each for every parameter set of ``params`` (the paper's test case).

    ``params`` is a provider such as `Cartesian`; without one the case runs once with the empty
    parameter set. The runner finds every ``TestCase`` defined at the top level of a test module.
    """

    __test__ = False  # not a pytest class, despite the name

    def __init__(
        self,
        name: str,
        phases: Sequence[Phase],
        params: ParameterProvider | Iterable[dict[str, Any]] | None = None,
    ) -> None:
        self.name = _check_name("test case", name)
        self.phases = list(phases)
        if not self.phases or not all(isinstance(p, Phase) for p in self.phases):
            raise TypeError(f"test case {name!r} needs a list of Phase objects, got {phases!r}")
        self.params = params

    def parameter_sets(self) -> list[ParameterSet]:
        """The parameter sets this case runs, in order."""
        if self.params is None:
            return [ParameterSet()]
        return [ParameterSet(values) for values in self.params]

    def __repr__(self) -> str:
        return f"TestCase({self.name!r}, {len(self.phases)} phases, params={self.params!r})"


class ValidationError(ValueError):
    """The test cases cannot run; ``problems`` lists every offender, one line each."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = problems
        super().__init__("invalid performance tests:\n  " + "\n  ".join(problems))


def case_problems(case: TestCase, files: bool = True) -> list[str]:
    """Every reason ``case`` cannot run: missing parameters, duplicate phases, no parameter sets;
    and, with ``files``, files its actions need that are not there (`Action.missing`)."""
    sets = case.parameter_sets()
    problems = [] if sets else [f"test case {case.name!r}: its parameter provider yields no sets"]
    seen: set[str] = set()
    for phase in case.phases:
        if phase.name in seen:
            problems.append(f"test case {case.name!r}: phase {phase.name!r} is defined twice")
        seen.add(phase.name)
        for action in phase.action.walk():
            problems += [
                f"test case {case.name!r}, phase {phase.name!r}: {problem}"
                for problem in action.problems() + (action.missing() if files else [])
            ]
        for param in sorted(phase.action.params_used()):
            lacking = [s.name for s in sets if param not in s]
            if lacking:
                problems.append(
                    f"test case {case.name!r}, phase {phase.name!r}: parameter "
                    f"{param!r} is missing from parameter set(s) {', '.join(lacking)}"
                )
    return problems


def validate_cases(cases: Sequence[TestCase], files: bool = True) -> None:
    """Raise `ValidationError` naming every problem of every case at once; do nothing if none.
    ``files``: whether the files the cases need are looked for (once they are chosen)."""
    problems: list[str] = [] if cases else ["no test cases were found"]
    names: set[str] = set()
    for case in cases:
        if case.name in names:
            problems.append(f"test case {case.name!r} is defined twice")
        names.add(case.name)
        problems.extend(case_problems(case, files))
    if problems:
        raise ValidationError(problems)
