"""The shapes of the messages Redline writes to a recording, checked as it is read: a message of
another shape (a sample without its time, a marker that is a number) failed ingestion with a
KeyError or TypeError after the upload was accepted, and its job stayed "uploaded" for good (a
hostile-input probe). A recording holding one is refused at upload, naming the message."""

from __future__ import annotations

from typing import Any

from redline.recording.driver import WORK_FIELDS

_NUMBER_OR_NONE = frozenset({int, float, type(None)})
#: a whole number a float holds (10**400 made ingestion raise OverflowError)
_LARGEST = 10**300


def _sample(item: Any) -> str:
    if type(item) is not dict:
        return "is not an object"
    if type(item.get("t_ns")) is not int:
        return "has no integer t_ns"
    if type(item.get("process")) is not str:
        return "has no process name"
    values = item.get("values")
    if type(values) is not dict:
        return "has no values object"
    if not _NUMBER_OR_NONE.issuperset(map(type, values.values())):
        return "has a value that is not a number"
    if any(type(value) is int and not -_LARGEST < value < _LARGEST for value in values.values()):
        return "has a number too large for a float"
    return ""


def _marker(item: Any) -> str:
    if type(item) is not dict:
        return "is not an object"
    if type(item.get("t_ns")) is not int:
        return "has no integer t_ns"
    if not all(type(item.get(key)) is str for key in ("case", "phase", "event")):
        return "lacks a case, phase or event string"
    if type(item.get("params")) is not dict:
        return "has no params object"
    return ""


def _report(item: Any) -> str:
    if type(item) is not dict:
        return "is not an object"
    if "t_ns" in item and type(item["t_ns"]) not in (int, float):  # a custom action's own
        return "has a t_ns that is not a number"
    if item.get("params") is not None and type(item["params"]) is not dict:
        return "has params that are not an object"
    work = WORK_FIELDS.get(str(item.get("action")))
    if work is not None and type(item.get(work, 0)) not in (int, float):
        return f"has a {work} count that is not a number"
    return ""


def keep_well_formed(counters: list[Any], markers: list[Any], driver: list[Any]) -> str:
    """Drop, in place, the messages not of the shapes Redline writes; the first one's
    description ("" when all are well formed)."""
    first = ""
    for what, items, problem_of in (
        ("counter sample", counters, _sample),
        ("phase marker", markers, _marker),
        ("driver report", driver, _report),
    ):
        kept = []
        for number, item in enumerate(items, 1):
            problem = problem_of(item)
            if not problem:
                kept.append(item)
            elif not first:
                first = f"{what} {number} {problem}: {str(item)[:80]!r}"
        items[:] = kept
    return first
