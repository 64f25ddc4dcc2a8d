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
from sqlalchemy import func, select, tuple_
from sqlalchemy.orm import Session, selectinload

#: revisions listed at most; the page and the API say how many more there are
MOST = 20


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
    return "measured, within the span of the regression's changes"


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
    shown = list(
        session.scalars(
            select(Revision)
            .where(*found)
            .order_by(Revision.order_key, Revision.id)
            .limit(MOST)
            .options(selectinload(Revision.jobs))
        )
    )
    if not shown:
        return [], 0
    total = session.scalar(select(func.count()).select_from(Revision).where(*found)) or 0
    series = select(Detection.series_id).where(Detection.regression_id == regression.id)
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
    listed = [
        RevisionBetween(title=revision.title, why=_why(revision, busy, measured))
        for revision in shown
    ]
    return listed, total
