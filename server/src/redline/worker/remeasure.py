"""A fresh run where the host was busy: an own execution of a revision with a phase measured
while other work loaded the host (`redline.recording.disturbance`) is run again, once per
disturbed execution and at most `REMEASURE_LIMIT` times per revision, for the disturbed test
cases only.

Without it a busy host silences detection: a disturbed phase is charted, never judged, so a
revision measured only while the host was busy has no verdict, and neither has the next one,
whose baseline it is — a trial from outside saw a 4x CPU regression pass `redline ci wait` that
way. The fresh run is one of the revision's own (`Job.pair` 0; a failed one leaves the
revision as it was, `redline.server.services.revisions.own_jobs`); it goes before other work
(`redline.server.services.jobs.lease_job`), and the CI verdict of a revision that waits for it,
its own or its baseline's, stays pending meanwhile (`redline.server.services.ci_verdict`).
"""

from __future__ import annotations

from collections.abc import Iterable

from redline.detect.result import NOT_ENOUGH_DATA
from redline.server.models import Detection, Job
from redline.worker.confirm_runs import FIRST_INDEX
from sqlalchemy import func, select
from sqlalchemy.orm import Session

#: fresh runs a revision may have in all: a host that stays busy leaves the verdict undecided
REMEASURE_LIMIT = 1


def queue_remeasure(session: Session, job: Job, cases: Iterable[str]) -> Job | None:
    """Queue a fresh run of the disturbed ``cases`` of an own ``job`` just ingested; None when
    it is a confirmation run, was run afresh already, or its revision used its fresh runs."""
    cases = sorted(set(cases))
    if not cases or job.pair != 0:
        return None
    if session.scalar(select(Job.id).where(Job.remeasures_job_id == job.id).limit(1)):
        return None  # an ingestion run again: its fresh run is queued already
    used = session.scalar(
        select(func.count()).where(
            Job.revision_id == job.revision_id, Job.remeasures_job_id.is_not(None)
        )
    )
    if (used or 0) >= REMEASURE_LIMIT:
        return None
    index = session.scalar(
        select(func.max(Job.execution_index)).where(
            Job.revision_id == job.revision_id, Job.execution_index < FIRST_INDEX
        )
    )
    fresh = Job(
        revision_id=job.revision_id,
        execution_index=(index or 0) + 1,
        remeasures_job_id=job.id,
        labels=list(job.labels or []),
        cases=cases,
    )
    session.add(fresh)
    session.flush()
    return fresh


def waiting_on(session: Session, revision_id: int) -> list[int]:
    """The revisions whose "not enough data" verdicts name this one as the baseline that was
    disturbed: judged again once its fresh run is ingested."""
    return list(
        session.scalars(
            select(Detection.revision_id)
            .where(
                Detection.baseline_revision_id == revision_id,
                Detection.verdict == NOT_ENOUGH_DATA,
                Detection.revision_id != revision_id,
            )
            .distinct()
        )
    )
