"""The CI gate's answer for one revision, in words for its page: what `redline ci` (failing on
regressions, its default) would say now, and the regressions behind a failure.

A trial read a revision's page for a confirmed regression and found the table and its verdict,
but not whether CI passed; `redline ci` and ``/verdict`` said it, the page did not.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from redline.detect.result import METHOD_FAILED, NOT_MEASURED_MARK
from redline.recording.disturbance import names_busy_host
from redline.recording.format import NO_TRAFFIC_MARK
from redline.server.models import Regression
from redline.server.schemas.alerts import CiVerdict, OpenRegression
from redline.server.services.ci_verdict import ci_verdict
from sqlalchemy import select
from sqlalchemy.orm import Session


@dataclass(frozen=True)
class Gate:
    #: pending, failed (a change for the worse), undecided, passed, or none (its jobs failed)
    state: str
    words: str
    #: the regressions of the revision's changes for the worse: (id, confirmation, its reason)
    regressions: tuple[tuple[int, str, str], ...] = ()
    #: the component's regressions still open before it, which the gate does not count, and
    #: how many there are in all (`redline.server.services.open_regressions`)
    before: tuple[OpenRegression, ...] = ()
    before_total: int = 0


def _plural(count: int, one: str) -> str:
    return f"{count} {one}{'' if count == 1 else 's'}"


#: what an undecided case's reason holds, and how the gate says it
_UNDECIDED = (
    (names_busy_host, "the host was busy"),
    (lambda reason: METHOD_FAILED in reason, "a method failed"),
    (
        lambda reason: NOT_MEASURED_MARK in reason,
        "a series the revision before measured is missing",
    ),
    (
        lambda reason: NO_TRAFFIC_MARK in reason,
        "the component took no part in the run (no traffic)",
    ),
)


def _why_undecided(verdict: CiVerdict) -> str:
    """Each cause among the undecided cases' reasons, once, in the order of `_UNDECIDED`: a page
    said "the host was busy or a method failed" of a series that had gone missing."""
    reasons = [case.reason for case in verdict.cases if case.state == "undecided"]
    causes = [said for found, said in _UNDECIDED if any(found(r) for r in reasons)]
    return " and ".join(causes) or "the host was busy or a method failed"


def _words(verdict: CiVerdict) -> tuple[str, str]:
    cases = len(verdict.cases)
    if verdict.state == "pending":
        return "pending", f"CI gate: pending, waiting for {verdict.waiting_for}."
    if verdict.state == "failed":
        return (
            "none",
            f"CI gate: no verdict, the jobs failed ({verdict.reason}); redline ci exits 3.",
        )
    if verdict.regressions:
        failing = sum(any(c["worse"] for c in case.changes) for case in verdict.cases)
        return "failed", (
            f"CI gate: fails: {_plural(verdict.regressions, 'change')} for the worse in "
            f"{_plural(failing, 'test case')} of {cases}; redline ci exits 1."
        )
    if verdict.undecided:
        return "undecided", (
            f"CI gate: undecided: {_plural(verdict.undecided, 'test case')} of {cases} without a "
            f"verdict because {_why_undecided(verdict)}; redline ci exits 4."
        )
    passed = sum(case.state == "passed" for case in verdict.cases)
    waiting = f"{_plural(verdict.skipped, 'test case')} without a verdict yet (not enough data)"
    if not passed:  # "0 passed" would read as a failure
        return "passed", f"CI gate: passes, nothing judged yet: {waiting}; redline ci exits 0."
    words = f"CI gate: passes: {_plural(passed, 'test case')} of {cases} passed"
    return "passed", words + (f", {waiting}" if verdict.skipped else "") + "; redline ci exits 0."


def gate(session: Session, component: str, title: str) -> Gate:
    verdict = ci_verdict(session, component, title)
    return replace(
        _gate(session, verdict),
        before=tuple(verdict.open_before),
        before_total=verdict.open_before_total,
    )


def _gate(session: Session, verdict: CiVerdict) -> Gate:
    state, words = _words(verdict)
    if state != "failed":
        return Gate(state, words)
    # the regressions of the changes the verdict fails on: not a dropped spike's, nor those of
    # a method that only charts (the page linked both beside a verdict that counted neither)
    failing = {
        change["regression"]
        for case in verdict.cases
        for change in case.changes
        if change["worse"] and change["regression"] is not None
    }
    found = session.execute(
        select(Regression.id, Regression.confirmation, Regression.confirmation_reason)
        .where(Regression.id.in_(failing))
        .order_by(Regression.id)
    )
    return Gate(state, words, tuple((row[0], row[1], row[2]) for row in found))
