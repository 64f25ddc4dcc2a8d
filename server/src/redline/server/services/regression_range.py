"""The revisions inside a regression's range: between its good revision (the newest its changes
were judged against) and its bad one (the newest showing it), other than those with one of its
changes, each with why it is not the good one.

A revision there was reported but not judged for the regression's series: its runs failed, were
cancelled, have not run yet, did not measure those series, or were measured while the host was
busy (charted, not judged). The change may be its; a new-user trial's regression page said
"After r4, shows at r6" and hid the r5 that the host was busy in.
"""

from __future__ import annotations

from redline.server.models import (
    Detection,
    Execution,
    Job,
    Regression,
    Revision,
    Summary,
    revision_place,
)
from redline.server.schemas.regressions import RevisionBetween
from redline.server.services.revisions import UNFINISHED, own_jobs, revision_state
from sqlalchemy import Select, func, literal, select, tuple_
from sqlalchemy.orm import Session, selectinload

#: revisions listed at most; the page and the API say how many more there are
MOST = 20
#: why a revision measured in a regression's range is not its good one
MEASURED = "measured, within the span of the regression's changes"


def _why(revision: Revision, busy: set[int], measured: set[int]) -> str:
    jobs = own_jobs(revision)
    state = revision_state([job.state for job in jobs], revision.analyzed_at is not None)
    if state in ("failed", "cancelled"):
        reasons = "; ".join(dict.fromkeys(job.reason for job in jobs if job.reason))
        return f"its runs {state}" + (f" ({reasons})" if reasons else "")
    if revision.id in busy:
        fresh = [
            job.state.value for job in jobs if job.remeasures_job_id and job.state in UNFINISHED
        ]
        again = f" (a fresh run of it is {fresh[0]})" if fresh else ""
        return f"the host was busy in its runs of these series: charted, not judged{again}"
    if state != "done":
        return f"not judged yet (its runs are {state})"
    if revision.id not in measured:
        return "it did not measure these series"
    return MEASURED


def revisions_between(
    session: Session, regression: Regression
) -> tuple[list[RevisionBetween], int]:
    """The revisions strictly between the regression's good and bad revisions, oldest first, at
    most `MOST`, each with why it is not the good one; and how many there are in all."""
    inside = (
        Revision.component_id == regression.component_id,
        revision_place() > tuple_(regression.good_key, regression.good_revision_id),
        revision_place() < tuple_(regression.bad_key, regression.bad_revision_id),
    )
    flagged = select(Detection.revision_id).where(Detection.regression_id == regression.id)
    found = (*inside, Revision.id.not_in(flagged))  # its own changes are listed already
    shown = _revisions(session, found, MOST)
    if not shown:
        return [], 0
    total = session.scalar(select(func.count()).select_from(Revision).where(*found)) or 0
    series = select(Detection.series_id).where(Detection.regression_id == regression.id)
    return _said(session, shown, series), total


def unmeasured_before(session: Session, detection: Detection) -> list[RevisionBetween]:
    """The revisions between a flagged change's baseline (the newest revision it was judged
    against) and its own revision that did not measure its series, oldest first, each with why:
    the change may be theirs. Per change, not per regression: a trial's change judged against
    the revision just before it was said to be maybe that revision's, "measured, within the
    span of the regression's changes", because another change of its regression reached back
    further."""
    if detection.baseline_revision_id is None:
        return []
    ends = [session.get_one(Revision, detection.baseline_revision_id)]
    ends.append(session.get_one(Revision, detection.revision_id))
    low, high = (tuple_(literal(r.order_key, Revision.order_key.type), literal(r.id)) for r in ends)
    inside = (
        Revision.component_id == ends[1].component_id,
        revision_place() > low,
        revision_place() < high,
    )
    shown = _revisions(session, inside, None)
    series = select(literal(detection.series_id))
    return [said for said in _said(session, shown, series) if said.why != MEASURED]


def _revisions(session: Session, where: tuple, limit: int | None) -> list[Revision]:
    return list(
        session.scalars(
            select(Revision)
            .where(*where)
            .order_by(Revision.order_key, Revision.id)
            .limit(limit)
            .options(selectinload(Revision.jobs))
        )
    )


def _said(session: Session, shown: list[Revision], series: Select) -> list[RevisionBetween]:
    """Each of ``shown`` with why it did not measure ``series`` (a query of series ids), or
    that it did (`MEASURED`)."""
    rows = session.execute(
        select(Execution.revision_id, Summary.disturbed)
        .join(Summary, Summary.execution_id == Execution.id)
        .join(Job, Job.id == Execution.job_id)
        .where(
            Execution.revision_id.in_([revision.id for revision in shown]),
            Job.pair == 0,  # its own runs: confirmation runs are no revision's results
            Summary.series_id.in_(series),
        )
        .distinct()
    ).all()
    measured = {revision_id for revision_id, disturbed in rows if not disturbed}
    busy = {revision_id for revision_id, disturbed in rows if disturbed} - measured
    return [
        RevisionBetween(title=revision.title, why=_why(revision, busy, measured))
        for revision in shown
    ]
