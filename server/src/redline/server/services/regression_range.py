"""The revisions inside a regression's range: between its good revision (the newest its changes
were judged against) and its bad one (the newest showing it), other than those with one of its
changes, each with why it is not the good one.

A revision there was reported but not judged for the regression's series: its runs failed, were
cancelled, have not run yet, did not measure those series, or were measured while the host was
busy (charted, not judged). The change may be its; a new-user trial's regression page said
"After r4, shows at r6" and hid the r5 that the host was busy in.
"""

from __future__ import annotations

from collections import defaultdict

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
    measured: dict[int, bool] = {}  # any of its series measured quietly: measured
    for by_revision in _measured(session, shown, series).values():
        for revision_id, busy in by_revision.items():
            measured[revision_id] = measured.get(revision_id, True) and busy
    return _said(shown, measured), total


def unmeasured_before(
    session: Session, detections: list[Detection]
) -> dict[int, list[RevisionBetween]]:
    """Per flagged change (by detection id), the revisions between its baseline (the newest
    revision it was judged against) and its own revision that did not measure its series,
    oldest first, at most `MOST`, each with why: the change may be theirs. Per change, not per
    regression: a trial's change judged against the revision just before it was said to be
    maybe that revision's, "measured, within the span of the regression's changes", because
    another change of its regression reached back further. Changes of one span share its reads
    (a verdict is polled while CI waits: a query or two a span, not a change)."""
    spans: dict[tuple[int, int], list[Detection]] = defaultdict(list)
    for detection in detections:
        if detection.baseline_revision_id is not None:
            spans[(detection.baseline_revision_id, detection.revision_id)].append(detection)
    found: dict[int, list[RevisionBetween]] = {}
    for (low_id, high_id), changes in spans.items():
        low, high = (session.get_one(Revision, i) for i in (low_id, high_id))
        inside = (
            Revision.component_id == high.component_id,
            revision_place() > tuple_(literal(low.order_key, Revision.order_key.type), low.id),
            revision_place() < tuple_(literal(high.order_key, Revision.order_key.type), high.id),
        )
        # the nearest ones: a baseline pinned long ago spans the whole history since
        shown = _revisions(session, inside, SPAN, newest=True)[::-1]
        if not shown:
            continue
        rows = _measured(session, shown, [d.series_id for d in changes])
        for detection in changes:
            said = _said(shown, rows.get(detection.series_id, {}))
            found[detection.id] = [r for r in said if r.why != MEASURED][:MOST]
    return found


#: revisions of a change's span read at most, the nearest to it
SPAN = 200


def _revisions(
    session: Session, where: tuple, limit: int | None, newest: bool = False
) -> list[Revision]:
    order = (
        (Revision.order_key.desc(), Revision.id.desc())
        if newest
        else (Revision.order_key, Revision.id)
    )
    return list(
        session.scalars(
            select(Revision)
            .where(*where)
            .order_by(*order)
            .limit(limit)
            .options(selectinload(Revision.jobs))
        )
    )


def _measured(
    session: Session, shown: list[Revision], series: Select | list[int]
) -> dict[int, dict[int, bool]]:
    """Per series of ``series`` (ids, or a query of them), per revision of ``shown`` with a
    summary of it from its own runs: whether every one was measured while the host was busy."""
    found: dict[int, dict[int, bool]] = defaultdict(dict)
    for revision_id, series_id, disturbed in session.execute(
        select(Execution.revision_id, Summary.series_id, Summary.disturbed)
        .join(Summary, Summary.execution_id == Execution.id)
        .join(Job, Job.id == Execution.job_id)
        .where(
            Execution.revision_id.in_([revision.id for revision in shown]),
            Job.pair == 0,  # its own runs: confirmation runs are no revision's results
            Summary.series_id.in_(series),
        )
        .distinct()
    ):
        seen = found[series_id]
        seen[revision_id] = seen.get(revision_id, True) and disturbed
    return found


def _said(shown: list[Revision], busy_in: dict[int, bool]) -> list[RevisionBetween]:
    """Each of ``shown`` with why it did not measure the series (``busy_in``: per revision
    with a summary of them, whether the host was busy in all its runs), or that it did."""
    measured = {revision_id for revision_id, busy in busy_in.items() if not busy}
    busy = {revision_id for revision_id, was in busy_in.items() if was}
    return [
        RevisionBetween(title=revision.title, why=_why(revision, busy, measured))
        for revision in shown
    ]
