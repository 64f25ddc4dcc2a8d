"""LNT's JSON report format, version 2 (``lnt importreport``, ``lnt.testing.Report``)::

    {"format_version": "2",
     "machine": {"name": "m1", ...},
     "run": {"start_time": "...", "end_time": "...", "llvm_project_revision": "1234", ...},
     "tests": [{"name": "suite/bench", "execution_time": [0.1, 0.11], "compile_time": 2.0}]}

Each test's metric becomes a series (case = test name, counter = metric); the run's order field
(``llvm_project_revision`` unless told otherwise) is the revision's title and sort key.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from datetime import datetime
from typing import Any

from redline.recording import SeriesKey, canonical_params
from redline.server.core.bodies import BadJson, parse_json
from redline.server.schemas.fields import (
    commit_time,
    git_commit,
    host_name,
    measurable,
    not_far_ahead,
    one_line,
    path_segment,
)
from redline.server.services.errors import BadRequest, Unprocessable
from redline.server.services.imports import IMPORT_PROCESS, ImportedRun

PHASE = "lnt"
ORDER_FIELD = "llvm_project_revision"


def _object(report: dict[str, Any], field: str) -> dict[str, Any]:
    value = report.get(field)
    if not isinstance(value, dict):
        raise BadRequest(f"LNT report: {field!r} must be an object")
    return value


def _values(test: str, metric: str, value: Any) -> list[float]:
    """A metric's samples; non-numeric metrics (hashes, statuses as text) give none."""
    items = value if isinstance(value, list) else [value]
    try:
        numbers = [
            float(item)
            for item in items
            if isinstance(item, int | float) and not isinstance(item, bool)
        ]
    except OverflowError:  # an integer beyond any float
        numbers = [math.inf]
    if any(not math.isfinite(number) for number in numbers):
        raise BadRequest(f"LNT report: test {test!r} metric {metric!r} is not a finite number")
    try:
        return [measurable(number) for number in numbers]
    except ValueError as exc:
        raise BadRequest(f"LNT report: test {test!r} metric {metric!r}: {exc}") from None


#: the longest name kept (a series' case and counter, a host's name, a revision's title)
NAME_LENGTH = 200


def _checked(where: str, value: str, check: Callable[[str], str] = one_line) -> str:
    """``value`` if ``check`` passes it and it is at most `NAME_LENGTH` characters long, else a
    BadRequest naming ``where``: a CR/LF in a test's name would break the pages' rows, and two
    tests' names cut to their first 200 characters were pooled into one series (a probe)."""
    if len(value) > NAME_LENGTH:
        raise BadRequest(
            f"LNT report: {where} {value[:80]!r}... is {len(value)} characters long "
            f"(at most {NAME_LENGTH})"
        )
    try:
        return check(value)
    except ValueError as exc:
        raise BadRequest(f"LNT report: {where} {value[:80]!r} {exc}") from None


def _commit(run: dict[str, Any]) -> tuple[str, str]:
    """Where the run names its commit (``git_sha``, else ``commit``) and what it says: checked
    as a CI report's commit is (a review stored ``--upload-pack=...`` as one)."""
    field = "git_sha" if "git_sha" in run else "commit"
    return f"run.{field}", str(run.get(field, ""))


def _samples(tests: Any) -> dict[SeriesKey, list[float]]:
    if not isinstance(tests, list) or not tests:
        raise BadRequest("LNT report: 'tests' must be a non-empty list")
    params = canonical_params({})
    samples: dict[SeriesKey, list[float]] = {}
    for index, test in enumerate(tests):
        name = test.get("name") if isinstance(test, dict) else None
        if not isinstance(name, str) or not name:
            raise BadRequest(f"LNT report: tests[{index}] has no 'name'")
        for metric, value in test.items():
            numbers = _values(name, metric, value) if metric != "name" else []
            if numbers:
                case = _checked(f"tests[{index}].name", name)
                counter = _checked(f"tests[{index}] metric", metric)
                key = SeriesKey(case, PHASE, params, IMPORT_PROCESS, counter)
                samples.setdefault(key, []).extend(numbers)
    if not samples:
        raise BadRequest("LNT report: no test has a numeric metric")
    return samples


def _run_time(run: dict[str, Any], field: str) -> datetime | None:
    """The run's ``field`` (start_time, end_time) as an ISO 8601 time checked like a revision's
    committed_at; absent, None; anything else an Unprocessable naming it."""
    text = run.get(field)
    if text is None:
        return None
    where = f"LNT report: run.{field} {str(text)[:40]!r}"
    if not isinstance(text, str):
        raise Unprocessable(f"{where} is not a valid ISO 8601 time (a {type(text).__name__})")
    try:
        when = datetime.fromisoformat(text)
    except ValueError as exc:
        raise Unprocessable(f"{where} is not a valid ISO 8601 time ({exc})") from None
    try:
        return commit_time(when)
    except ValueError as exc:
        raise Unprocessable(f"{where}: {exc}") from None


def _run_meta(run: dict[str, Any]) -> dict[str, str]:
    """What the execution keeps of the run: its format, and its times when given."""
    start, end = _run_time(run, "start_time"), _run_time(run, "end_time")
    if start is not None and end is not None and end < start:
        raise Unprocessable(
            f"LNT report: run.end_time {end.isoformat()} is before the run's start_time "
            f"{start.isoformat()}"
        )
    times = {"start_time": start, "end_time": end}
    return {"imported": "lnt"} | {k: v.isoformat() for k, v in times.items() if v is not None}


def _text(holder: dict[str, Any], field: str, where: str) -> str:
    """``holder[field]`` when it is text ('' when absent); a BadRequest naming it otherwise (a
    NaN machine name became a host called "nan")."""
    value = holder.get(field, "")
    if not isinstance(value, str):
        raise BadRequest(f"LNT report: {where}.{field} must be text, not {value!r}"[:200])
    return value


def parse_lnt(body: bytes, component: str, order_field: str = ORDER_FIELD) -> ImportedRun:
    """The run an LNT v2 report describes; BadRequest naming the field at fault otherwise."""
    try:
        report = parse_json(body)
    except BadJson as exc:
        raise BadRequest(f"LNT report: {exc}") from None
    if not isinstance(report, dict):
        raise BadRequest(f"LNT report: the body must be a JSON object, not {type(report).__name__}")
    if "format_version" not in report:  # "version 1 is not read" said of none, a trial read
        raise BadRequest("LNT report: 'format_version' is missing: LNT's format 2 says \"2\"")
    if str(report.get("format_version")) != "2":
        raise BadRequest(
            f"LNT report: 'format_version' is {str(report['format_version'])[:20]!r}: only "
            '"2" is read (version 1 is not)'
        )
    machine, run = _object(report, "machine"), _object(report, "run")
    order = run.get(order_field)
    if order is None or order == "":
        raise BadRequest(f"LNT report: run has no order field {order_field!r}")
    if not isinstance(order, str | int) or isinstance(order, bool):
        # a NaN read as "no order field" sent its author looking for a missing one
        said = f"must be text or a whole number, not {order!r}"[:120]
        raise BadRequest(f"LNT report: run field {order_field!r} {said}")
    # an order that reads as a Unix time years ahead sorts above every later run (`SortKey`)
    title = _checked(f"run field {order_field!r}", str(order), not_far_ahead)
    try:
        path_segment(title)
    except ValueError as exc:  # the revision's title must be addressable in the API's URLs
        raise BadRequest(f"LNT report: run field {order_field!r} ({title[:80]!r}) {exc}") from None
    return ImportedRun(
        component=component,
        revision=title,
        sort_key=title,
        commit=_checked(*_commit(run), git_commit),
        host=_checked("machine.name", _text(machine, "name", "machine"), host_name),
        samples=_samples(report.get("tests")),
        meta=_run_meta(run),
    )
