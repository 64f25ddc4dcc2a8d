"""The view a component page's address asks for (`TrendView.from_query`): filters by case,
phase, process, counter, parameter (``param.legs=8``) and host, how many of the newest
revisions, where the history ends (``before``), log scale and a moving median; the values
each filter can take, with a clear refusal of one that no series has (`check_filters`); the
order of its charts (`chart_place`) and how many one page draws (`cut_charts`).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any
from urllib.parse import urlencode

from redline.detect.counters import kind
from redline.recording import params_name
from redline.server.models import Component
from redline.server.services.errors import BadRequest
from redline.server.services.read import FIELDS, Identified, matches, param_text

DEFAULT_REVISIONS = 100
MAX_REVISIONS = 2000
MAX_FILTER_LENGTH = 200
#: the most charts, and series drawn in them, of one page: a trial's import of 20,000 series
#: made an unfiltered page of 30 MB that took 5 s to answer, and longer to draw
MAX_CHARTS = 60
MAX_SERIES = 400


@dataclass(frozen=True)
class TrendView:
    """What a trend page shows; ``query()`` gives the address that shows it again."""

    case: str = ""
    phase: str = ""
    process: str = ""
    counter: str = ""
    host: str = ""  # a performance host's name: only the executions it ran
    params: tuple[tuple[str, str], ...] = ()
    revisions: int = DEFAULT_REVISIONS
    before: str = ""  # a revision's title: the history up to, not including, it
    log: bool = False
    median: bool = False
    #: the flags of methods that only chart, besides the changes of regressions: KS at one
    #: execution a revision flags most unchanged ones (a trial read them as alarms)
    flags: bool = False

    @classmethod
    def from_query(cls, query: Mapping[str, str]) -> TrendView:
        """The view an address asks for; a clear `BadRequest` naming a bad value."""
        for key, value in query.items():
            if len(value) > MAX_FILTER_LENGTH:
                raise BadRequest(f"{key}: at most {MAX_FILTER_LENGTH} characters")
            if any(ord(c) < 32 or ord(c) == 127 for c in value):  # a NUL reached the database
                raise BadRequest(f"{key}: must not contain control characters")
        raw = query.get("revisions", str(DEFAULT_REVISIONS)) or str(DEFAULT_REVISIONS)
        if not (raw.isascii() and raw.isdecimal()) or not 1 <= int(raw) <= MAX_REVISIONS:
            raise BadRequest(f"revisions: a whole number from 1 to {MAX_REVISIONS}, not {raw!r}")
        params = tuple(
            sorted(
                (key.removeprefix("param."), value)
                for key, value in query.items()
                if key.startswith("param.") and value
            )
        )
        return cls(
            **{name: query.get(name, "") for name in FIELDS},
            host=query.get("host", ""),
            params=params,
            revisions=int(raw),
            before=query.get("before", ""),
            log=_flag(query, "log"),
            median=_flag(query, "median"),
            flags=_flag(query, "flags"),
        )

    def query(self, **changes: Any) -> str:
        """The query string of this view with ``changes`` (defaults left out): shareable."""
        view = replace(self, **changes)
        pairs: list[tuple[str, str]] = [(n, getattr(view, n)) for n in FIELDS if getattr(view, n)]
        pairs += [("host", view.host)] if view.host else []
        pairs += [(f"param.{name}", value) for name, value in view.params]
        if view.revisions != DEFAULT_REVISIONS:
            pairs.append(("revisions", str(view.revisions)))
        if view.before:
            pairs.append(("before", view.before))
        pairs += [(name, "1") for name in ("log", "median", "flags") if getattr(view, name)]
        return urlencode(pairs)

    def selects(self, series: Identified) -> bool:
        fields: dict[str, str | None] = {name: getattr(self, name) or None for name in FIELDS}
        return matches(series, fields, dict(self.params))


#: what a switch in an address may say (a checkbox sends "on")
FLAG_VALUES = {
    "1": True,
    "on": True,
    "true": True,
    "": False,
    "0": False,
    "off": False,
    "false": False,
}


def _flag(query: Mapping[str, str], name: str) -> bool:
    value = query.get(name, "")
    if value.lower() not in FLAG_VALUES:
        raise BadRequest(f"{name}: 1 or 0 (on or off), not {value!r}")
    return FLAG_VALUES[value.lower()]


@dataclass(frozen=True)
class Identity:
    """What a view selects, orders and cuts a series by, without what the API shows of it (a
    `SeriesRef` each took 1.4 s for 20,000 series, of which a page draws 400 at most)."""

    case: str
    phase: str
    process: str
    counter: str
    params: Mapping[str, Any]


def filter_choices(refs: list[Identified]) -> dict[str, list[str]]:
    """filter -> the values it can take; ``param.NAME`` -> the parameter's values."""
    values = {name: [getattr(ref, name) for ref in refs] for name in FIELDS}
    return choices_of(values, [ref.params for ref in refs])


def choices_of(
    values: Mapping[str, Iterable[str]], param_sets: Iterable[Mapping[str, Any]]
) -> dict[str, list[str]]:
    """The choices of each filter of `FIELDS` among ``values``, and of each parameter among
    ``param_sets``: in numeric order, then text."""
    found: dict[str, set[str]] = {name: set(values.get(name, ())) for name in FIELDS}
    for params in param_sets:
        for name, value in params.items():
            found.setdefault(f"param.{name}", set()).add(param_text(value))
    return {name: sorted(values, key=_numbers_first) for name, values in found.items()}


def check_filters(component: Component, view: TrendView, refs: list[Identified]) -> None:
    """A `BadRequest` naming a filter value that no series of the component has, with the
    values it can take (a trial's ``?case=nosuch`` read "No results for this view yet", as if
    results were on their way); filters each of which matches, but not together, pass."""
    can = filter_choices(refs)
    asked = [(name, getattr(view, name)) for name in FIELDS if getattr(view, name)]
    for name, value in asked + [(f"param.{name}", value) for name, value in view.params]:
        values, parameter = can.get(name), name.removeprefix("param.")
        if values is None:
            known = [key.removeprefix("param.") for key in can if key.startswith("param.")]
            raise BadRequest(
                f"{name}: {component.name} has no parameter {parameter!r} (its parameters: "
                f"{', '.join(known) or 'none'})"
            )
        if value not in values:
            shown = ", ".join(repr(v) for v in values[:10]) + (", ..." if len(values) > 10 else "")
            if name in FIELDS:
                raise BadRequest(
                    f"{name}: {component.name} has no {name} {value!r} (it has {shown})"
                )
            raise BadRequest(
                f"{name}: {component.name}'s parameter {parameter!r} is never {value!r} (it is "
                f"{shown})"
            )


def _numbers_first(value: str) -> tuple[bool, float, str]:
    """Numbers in numeric order ("50" before "100"), then any other text in text order."""
    try:
        number = float(value)
    except ValueError:
        return True, 0.0, value
    return (False, number, value) if math.isfinite(number) else (True, 0.0, value)


#: a chart: the case, phase, process and counter its lines (parameter sets) share
ChartKey = tuple[str, str, str, str]
#: the order of a test case's charts by whose series they are: the component's own first
CHART_KINDS = {"counter": 0, "driver": 1, "host": 2, "redline": 3, "recorder": 4}


def chart_key(ref: Identified) -> ChartKey:
    return ref.case, ref.phase, ref.process, ref.counter


def chart_place(key: ChartKey) -> tuple[Any, ...]:
    """Where a chart goes: the suite's test cases before Redline's own ("@run", the
    recorder's counts), and in each the component's counters, then the driver's metrics, then
    the machine's and Redline's. A trial's unfiltered page opened with four flat recorder
    charts above the component's CPU."""
    case, phase, process, counter = key
    return (case.startswith("@"), case, phase, CHART_KINDS.get(kind(process), 0), process, counter)


def cut_charts(refs: Mapping[int, Identified]) -> tuple[set[int], str]:
    """The series (by id) of the charts one page draws, the first in `chart_place` order up to
    `MAX_CHARTS` charts and `MAX_SERIES` series (of a first chart with more lines, the first
    `MAX_SERIES` by parameter set); and, when that is not all of ``refs``, what the page says of
    the rest ('' when it is)."""
    charts: dict[ChartKey, list[int]] = defaultdict(list)
    for series_id, ref in refs.items():
        charts[chart_key(ref)].append(series_id)
    if len(charts) <= MAX_CHARTS and len(refs) <= MAX_SERIES:
        return set(refs), ""
    kept: list[int] = []
    drawn = 0
    for key in sorted(charts, key=chart_place):
        lines = sorted(charts[key], key=lambda series_id: params_name(dict(refs[series_id].params)))
        if drawn == MAX_CHARTS or (kept and len(kept) + len(lines) > MAX_SERIES):
            break
        kept += lines[:MAX_SERIES]
        drawn += 1
    note = (
        f"This view holds {len(refs):,} series in {_charts(len(charts))}; the page draws the "
        f"first {_charts(drawn)} ({len(kept):,} series). Choose a case, phase, process, counter "
        "or parameter above to see the others."
    )
    return set(kept), note


def _charts(count: int) -> str:
    return f"{count:,} chart" + ("" if count == 1 else "s")
