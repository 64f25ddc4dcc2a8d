"""The CI gate's answer for one revision, in words for its page: what `redline ci` (failing on
regressions, its default) would say now, and the regressions behind a failure.

A trial read a revision's page for a confirmed regression and found the table and its verdict,
but not whether CI passed; `redline ci` and ``/verdict`` said it, the page did not.
"""

from __future__ import annotations

from dataclasses import dataclass

from redline.server.models import Detection, Regression
from redline.server.schemas.alerts import CiVerdict
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


def _plural(count: int, one: str) -> str:
    return f"{count} {one}{'' if count == 1 else 's'}"


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
            "verdict because the host was busy or a method failed; redline ci exits 4."
        )
    passed = sum(case.state == "passed" for case in verdict.cases)
    waiting = f"{_plural(verdict.skipped, 'test case')} without a verdict yet (not enough data)"
    if not passed:  # "0 passed" would read as a failure
        return "passed", f"CI gate: passes, nothing judged yet: {waiting}; redline ci exits 0."
    words = f"CI gate: passes: {_plural(passed, 'test case')} of {cases} passed"
    return "passed", words + (f", {waiting}" if verdict.skipped else "") + "; redline ci exits 0."


def gate(session: Session, component: str, title: str, revision_id: int) -> Gate:
    verdict = ci_verdict(session, component, title)
    state, words = _words(verdict)
    if state != "failed":
        return Gate(state, words)
    found = session.execute(
        select(Regression.id, Regression.confirmation, Regression.confirmation_reason)
        .join(Detection, Detection.regression_id == Regression.id)
        .where(Detection.revision_id == revision_id)
        .distinct()
        .order_by(Regression.id)
    )
    return Gate(state, words, tuple((row[0], row[1], row[2]) for row in found))
