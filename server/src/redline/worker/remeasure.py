"""A fresh run of a baseline the host was busy in: when a revision's new results cannot be
judged because every run of its baseline revision was measured while other work loaded the host
(`redline.recording.disturbance`; the agent already ran each of them again, at once), the
baseline revision gets one fresh run of its whole suite, at most `REMEASURE_LIMIT` per revision,
and the revision is judged again once it is ingested (`redline.server.services.fresh_runs`),
or without it once it has ended without results. The whole suite, not the
test cases concerned: the component runs the cases one after another without a restart, so what
one case measures depends on those before it (a trial's fresh run of only its `stats` case found
the component's RSS at 26 MB against 92 MB after its `stream` case, and the next, README-only
revision was flagged for memory against it).

Without it a busy host silences detection: a disturbed phase is charted, never judged, so the
revision after one measured only while the host was busy had no verdict — a trial from outside
saw a 4x CPU regression pass `redline ci wait` that way. The same goes for a revision between
a flagged change and its baseline that the host was busy in: the change may be its, and the
flagged revision's confirmation runs and CI verdict wait for its fresh run, after which both
are judged again in order. Machine time is spent only where a
verdict waits for it: a revision's own disturbed runs are not run again by the server (its
verdict is "undecided", `redline.server.services.ci_verdict`) unless a later revision needs
them as its baseline. The fresh run is one of the baseline revision's own (`Job.pair` 0; a
failed one leaves that revision as it was, `redline.server.services.revisions.own_jobs`), it
goes before other work (`redline.server.services.jobs.lease_job`), and the CI verdict of the
revision waiting for it stays pending meanwhile.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from redline.detect.confirmation import SUSPECTED
from redline.detect.result import NOT_ENOUGH_DATA
from redline.recording.disturbance import names_busy_host
from redline.server.models import (
    FINISHED,
    Detection,
    Execution,
    Job,
    Revision,
    Series,
    Summary,
    revision_place,
)
from redline.server.services.reach import ingested_executions
from sqlalchemy import func, select
from sqlalchemy.orm import Session

#: fresh runs a revision may have in all: a host that stays busy leaves the verdict undecided
REMEASURE_LIMIT = 1


def queue_for_baselines(
    session: Session, revision: Revision, rows: list[dict[str, Any]], baseline: str = "recent"
) -> list[Job]:
    """A fresh run of each baseline revision that ``rows`` (the revision's new verdicts) could
    not be judged against because the host was busy in all its runs, and of each revision
    between a suspected change's baseline and this one whose runs of its series the host was
    busy in (`busy_between`): the change may be theirs, and without it this revision would be
    blamed for it (`bench_verdicts`: the timeouts injected at r24, all of whose runs were
    disturbed, made a regression of r25, whose code had not changed). Not for a revision that
    was itself run afresh: its verdicts are judged again for the revision that waited for it,
    and its own baseline's runs are no one's wait (one level, never a walk back through a busy
    history)."""
    if any(job.remeasures_job_id is not None for job in revision.jobs):
        return []
    wanted: dict[int, set[int]] = {}
    for row in rows:
        if (
            row["verdict"] == NOT_ENOUGH_DATA
            and row["baseline_revision_id"] is not None
            and names_busy_host(row["reason"])
        ):
            wanted.setdefault(row["baseline_revision_id"], set()).add(row["series_id"])
    spans = (
        session.execute(
            select(Detection.series_id, Detection.baseline_revision_id)
            .where(
                Detection.revision_id == revision.id,
                Detection.confirmation == SUSPECTED,
                Detection.baseline_revision_id.is_not(None),
            )
            .distinct()
        ).all()
        # a pinned baseline never takes in the revisions after it, nor "previous" those between
        if baseline in ("recent", "window")
        else []
    )
    for series_id, baseline_id in spans:
        for revision_id in busy_between(session, series_id, baseline_id, revision):
            wanted.setdefault(revision_id, set()).add(series_id)
    queued = []
    for revision_id, series in sorted(wanted.items()):
        cases = session.scalars(select(Series.case).where(Series.id.in_(series)).distinct())
        job = queue_remeasure(session, revision_id, cases)
        if job is not None:
            queued.append(job)
    return queued


def busy_between(
    session: Session, series_id: int, baseline_id: int | None, revision: Revision
) -> list[int]:
    """The revisions between a change's baseline revision and ``revision`` (where it was
    flagged) whose every run of the series was measured while the host was busy: unjudged,
    so the change may be theirs."""
    if baseline_id is None:
        return []
    baseline = session.get_one(Revision, baseline_id)
    unfinished = select(Job.id).where(
        Job.revision_id == Execution.revision_id,
        Job.pair == 0,
        Job.state.not_in(FINISHED),
    )
    return list(
        session.scalars(
            select(Execution.revision_id)
            .join(Summary, Summary.execution_id == Execution.id)
            .join(Revision, Revision.id == Execution.revision_id)
            .where(
                Summary.series_id == series_id,
                Revision.component_id == revision.component_id,
                revision_place() > baseline.place,
                revision_place() < revision.place,
                Execution.id.in_(ingested_executions()),
                ~unfinished.exists(),  # its own runs not all in: its fresh run would be early
            )
            .group_by(Execution.revision_id)
            .having(func.bool_and(Summary.disturbed))
        )
    )


def queue_remeasure(session: Session, revision_id: int, cases: Iterable[str]) -> Job | None:
    """Queue a fresh run of the revision's whole suite, for the ``cases`` concerned; None when
    none are, when it had its fresh runs, or when no agent measured it (imported results: none
    runs them again)."""
    wanted = sorted(set(cases))
    revision = session.get_one(Revision, revision_id)
    jobs = [job for job in revision.jobs if job.pair == 0]
    fresh = [job for job in jobs if job.remeasures_job_id is not None]
    measured = [job for job in jobs if job.remeasures_job_id is None and job.attempts > 0]
    if not wanted or len(fresh) >= REMEASURE_LIMIT or not measured:
        return None
    job = Job(
        revision_id=revision_id,
        execution_index=max(job.execution_index for job in jobs) + 1,
        remeasures_job_id=min(measured, key=lambda job: job.execution_index).id,
        labels=list(measured[0].labels or []),
        cases=[],  # every case, in the suite's order: a case's state depends on those before
    )
    session.add(job)
    session.flush()
    return job
