"""The wait for a fresh run (`redline.worker.remeasure`): which revisions are being run afresh
because the host was busy in all their runs, which revisions wait for one (their baseline, or a
suspected change whose span holds it), and what becomes of those when it ends without results.

A fresh run that ends with a recording is ingested, and its ingestion has the revisions that
waited judged again (`redline.worker.ingest`). One that ends without (its host failed it, its
leases lapsed until it was failed, its upload or its ingestion was refused, it was cancelled
with its revision) marks them not yet analysed in the same transaction (`mark_waiting`):
their CI verdicts wait, and they are judged again without it, at once when the API hears of it
from the host, else by the periodic sweep (`redline.worker.sweeps.unjudged_after_fresh_runs`);
a suspected change then gets the confirmation runs it was held back from. Before, a failed
fresh run left such a change suspected with no pairs ever queued, and its CI verdict turned to a
regression nothing had confirmed.
"""

from __future__ import annotations

from collections.abc import Sequence

from redline.detect.confirmation import SUSPECTED
from redline.detect.result import NOT_ENOUGH_DATA
from redline.server.db import lock_component
from redline.server.models import (
    FINISHED,
    Detection,
    Job,
    Revision,
    revision_place,
)
from redline.server.services.analysed import unanalysed
from sqlalchemy import ColumnElement, and_, select, tuple_
from sqlalchemy.orm import Session, aliased


def fresh_runs_under_way(component_id: int):  # noqa: ANN201 - a query to narrow
    """The titles of the component's revisions being run afresh because the host was busy in
    all their runs (`redline.worker.remeasure`), as a query."""
    return (
        select(Revision.title)
        .join(Job, Job.revision_id == Revision.id)
        .where(
            Revision.component_id == component_id,
            Job.remeasures_job_id.is_not(None),
            Job.state.not_in(FINISHED),
        )
    )


def _span(
    session: Session, revision: Revision, baselines: Sequence[int | None]
) -> ColumnElement[bool] | None:
    """Revisions after the oldest of ``baselines`` and before ``revision``; None when there
    are no baselines."""
    places = [session.get_one(Revision, b).place for b in set(baselines) if b is not None]
    if not places:
        return None
    return and_(revision_place() > min(places), revision_place() < revision.place)


def fresh_run_between(
    session: Session, revision: Revision, baselines: Sequence[int | None]
) -> str | None:
    """The title of a revision after the oldest of ``baselines`` (the baseline revisions of
    ``revision``'s suspected changes) and before ``revision`` that is being run afresh because
    the host was busy in all its runs (`redline.worker.remeasure`): the change may be its, so
    the suspected revision's confirmation runs and CI verdict wait for it. None when none is."""
    span = _span(session, revision, baselines)
    if span is None:
        return None
    return session.scalar(fresh_runs_under_way(revision.component_id).where(span).limit(1))


def waiting_on(session: Session, revision_id: int) -> list[int]:
    """The revisions judged again once this one's fresh run has ended: those whose "not
    enough data" verdicts name it as their baseline, and those with a suspected change whose
    span (baseline, revision) holds it (`redline.worker.remeasure.busy_between`), however far
    after it they are; oldest first."""
    revision = session.get_one(Revision, revision_id)
    baseline, flagged = aliased(Revision), aliased(Revision)
    spanning = (
        select(Detection.revision_id)
        .join(baseline, baseline.id == Detection.baseline_revision_id)
        .join(flagged, flagged.id == Detection.revision_id)
        .where(
            flagged.component_id == revision.component_id,
            Detection.confirmation == SUSPECTED,
            tuple_(baseline.order_key, baseline.id) < revision.place,
            tuple_(flagged.order_key, flagged.id) > revision.place,
        )
    )
    lacking = select(Detection.revision_id).where(
        Detection.baseline_revision_id == revision_id,
        Detection.verdict == NOT_ENOUGH_DATA,
        Detection.revision_id != revision_id,
    )
    # in the revisions' order, the order to judge them in: a UNION's own order is Postgres's
    # (a CI run judged r7 before r6)
    waiting = lacking.union(spanning).subquery()
    return list(
        session.scalars(
            select(Revision.id)
            .where(Revision.id.in_(select(waiting.c[0])))
            .order_by(Revision.order_key, Revision.id)
        )
    )


def mark_waiting(session: Session, revision_id: int) -> list[int]:
    """In the transaction that ends a fresh run of ``revision_id`` without results: the
    revisions that waited for it (`waiting_on`) are marked not yet analysed, so that their CI
    verdicts wait, and returned after it, in the order to judge them; nothing when none waited.

    The component's row is locked first (`lock_component`), as every store of a revision's
    verdicts does before it reads whether a fresh run is under way: a store under way finishes
    first, and its suspected change is among those found; a store after this one reads the
    fresh run as ended and queues its confirmation runs itself."""
    lock_component(session, session.get_one(Revision, revision_id).component_id)
    waiting = waiting_on(session, revision_id)
    if not waiting:
        return []
    unanalysed(session, waiting)
    return [revision_id, *waiting]
