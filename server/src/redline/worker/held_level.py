"""A level the later revisions hold, found at the revision whose own run missed it.

With one execution a revision, a change's own run is judged on one value, within the noise of
one run: CPU +10 % and the round trip +20 % went unflagged in `bench_verdicts` at their
revision, and then pooled into the baseline of the next ones, each again judged on one value.
Perfherder's fore window judges a revision on the runs after it too. Here, once `HELD_AFTER`
revisions from a revision on are measured (this one the last), that revision is judged again on
their values against the baseline revisions before it (`ExecutionShift.held`): four values
against one shrink the noise of the new level by half. A level they hold becomes that
revision's suspected change, grouped into a regression, and its own confirmation pairs, against
its own baseline revision, decide it as any flag's do (`confirm_runs.confirm_found_late`).

Only where pairs can decide: the component confirms by re-running and an agent measured the
revision (imported results are left as judged), and only when new results are judged, not in
a re-analysis (which queues no machine time; the verdicts found so are kept through it,
`found_late.still_moved`). Like a change moved back (`redline.worker.found_late`), its own runs
missed it, so the history does not settle it when its pairs cannot run, and it is never moved
back again.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from redline.detect.confirmation import LEVEL_HELD
from redline.detect.execution_shift import HELD_AFTER
from redline.server.models import Revision
from redline.worker.baselines import Step
from redline.worker.confirm_runs import confirm_found_late, rerunnable
from redline.worker.rows import step_row
from sqlalchemy import select
from sqlalchemy.orm import Session


def held_level(
    series_id: int, step: Step | None, counter: str, judged: Revision
) -> dict[str, Any] | None:
    """The verdict of the revision `HELD_AFTER` revisions back (``judged`` the last of them) as
    a row of that revision's, when they hold a level its own run(s) did not show (``step``:
    `Baselines.held`'s answer); None when they do not, or it could not be asked."""
    return step_row(
        series_id,
        step,
        counter,
        lambda step: (
            f"{LEVEL_HELD}, when {judged.title} was judged: the {HELD_AFTER} "
            f"revisions from it on hold a new level ({len(step.after)} values against the "
            f"{step.values_before} before it), which its own run(s) alone did not show beyond "
            "the noise"
        ),
    )


def is_held(row: dict[str, Any]) -> bool:
    return str(row["reason"]).startswith(LEVEL_HELD)


def rerunnable_only(session: Session, rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` less the held levels (`held_level`) of revisions that cannot have pairs of their
    own (no agent measured them): those revisions keep their verdicts as judged."""
    held = {row["revision_id"] for row in rows if is_held(row)}
    if not held:  # nearly always
        return list(rows)
    can = {
        revision.id
        for revision in session.scalars(select(Revision).where(Revision.id.in_(held)))
        if rerunnable(session, revision)
    }
    return [row for row in rows if not is_held(row) or row["revision_id"] in can]


def confirm_held(session: Session, rows: Sequence[dict[str, Any]]) -> None:
    """Pairs for each revision a held level was stored at, oldest first."""
    held = {row["revision_id"] for row in rows if is_held(row)}
    if not held:
        return
    for revision in session.scalars(
        select(Revision).where(Revision.id.in_(held)).order_by(Revision.order_key, Revision.id)
    ):
        confirm_found_late(session, revision)
