"""What a lost message would leave undone, found again by the periodic re-queue task
(`redline.worker.tasks.requeue_stale_uploads`): the commit status of revisions whose jobs ended
failed (no ingest follows them), the revisions that waited for a fresh run that ended without a
recording, the revisions whose detection was lost, and the alerts of run-time alarms whose task
never ran.
"""

from __future__ import annotations

from datetime import datetime, timedelta

from redline.recording.format import COMMIT_HASH
from redline.server.models import (
    DID_NOT_RUN,
    UNENDED,
    Alert,
    Component,
    Delivery,
    Job,
    JobState,
    Revision,
    RuntimeAlarm,
    Subscription,
    revision_place,
    utcnow,
)
from redline.server.services.fresh_runs import waiting_on
from redline.worker.alerts import runtime_listeners
from redline.worker.onward import WALK_LOCK
from sqlalchemy import cast, func, select, text
from sqlalchemy.dialects.postgresql import JSONB
from sqlalchemy.orm import Session, aliased

#: how far back the sweeps look for revisions whose jobs ended without a judgement, and for
#: run-time alarms no subscription was told of
SWEEP_WITHIN = timedelta(days=2)
#: and how old what they pick up must be: younger, the message queued for it may be on its way
SWEEP_GRACE = timedelta(minutes=2)
#: how long a component's jobs stand still before its revisions still marked not yet analysed
#: are taken for lost detections (`unjudged_revisions`): longer than any detection takes
LOST_GRACE = timedelta(minutes=30)


def failed_without_status(session: Session, now: datetime | None = None) -> list[int]:
    """Revisions of a commit hash (`commit_status` posts none for another), of components that
    post commit statuses, whose jobs have all ended (in the last `SWEEP_WITHIN`, `SWEEP_GRACE`
    ago at least), one of their own failed or cancelled, and with no final status yet: no
    ingest follows such a job, so nothing else would post the verdict (a build that fails,
    leases that lapse until the job is failed, a host that gives up)."""
    now = now or utcnow()
    other = aliased(Job)
    unsettled = select(other.id).where(other.revision_id == Revision.id, other.state.in_(UNENDED))
    final = select(Delivery.id).where(
        Delivery.key.in_(
            [
                func.concat("status:", Revision.id, f":{state}")
                for state in ("success", "failure", "error")
            ]
        )
    )
    return list(
        session.scalars(
            select(Revision.id)
            .join(Component, Component.id == Revision.component_id)
            .join(Job, Job.revision_id == Revision.id)
            .where(cast(Component.commit_status, JSONB).has_key("provider"))
            .where(Revision.commit.regexp_match(COMMIT_HASH.pattern))  # what gets a status
            .where(Job.pair == 0, Job.state.in_((JobState.failed, JobState.cancelled)))
            .where(Job.updated.between(now - SWEEP_WITHIN, now - SWEEP_GRACE))
            .where(~unsettled.exists(), ~final.exists())
            .distinct()
        )
    )


def unjudged_after_fresh_runs(session: Session, now: datetime | None = None) -> list[list[int]]:
    """What to judge again, in order (the revision, then those that waited for it), for each
    fresh run of a busy revision that ended without results (in the last `SWEEP_WITHIN`,
    `SWEEP_GRACE` ago at least) while a revision that waited for it is still marked not yet
    analysed (`redline.server.services.fresh_runs.mark_waiting`): its leases lapsed until
    it was failed, its upload or ingestion was refused, it was cancelled, or the API's message
    for a host's failure got lost. Once judged, a revision is left alone; one that cannot be
    judged is asked for again at each sweep, within the window."""
    now = now or utcnow()
    found = []
    for revision_id in session.scalars(
        select(Job.revision_id)
        .where(Job.remeasures_job_id.is_not(None), Job.state.in_(DID_NOT_RUN))
        .where(Job.updated.between(now - SWEEP_WITHIN, now - SWEEP_GRACE))
        .distinct()
        .order_by(Job.revision_id)
    ):
        unjudged = session.scalars(
            select(Revision.id)
            .where(Revision.id.in_(waiting_on(session, revision_id)))
            .where(Revision.analyzed_at.is_(None))
            .order_by(Revision.id)
        ).all()
        if unjudged:
            found.append([revision_id, *unjudged])
    return found


def unjudged_revisions(
    session: Session, now: datetime | None = None, limit: int = 200
) -> list[list[int]]:
    """Per component, in history order, its revisions marked not yet analysed
    (`redline.server.services.analysed`) that have a run ingested, when the component's jobs
    last moved within `SWEEP_WITHIN` but not in the last `LOST_GRACE`, and no walk of it is
    under way (`redline.worker.onward.taking_turns`): the detection queued after their
    ingestion or import was lost (the broker away as it was queued, say), and their CI verdicts
    would wait for ever. The caller queues them only while no detection or ingestion waits in
    the broker (`redline.worker.tasks.requeue_stale_uploads`): one waiting may be theirs. At
    most ``limit`` revisions."""
    now = now or utcnow()
    other = aliased(Revision)
    jobs = select(func.max(Job.updated)).join(other, other.id == Job.revision_id)
    last_moved = jobs.where(other.component_id == Revision.component_id).scalar_subquery()
    ingested = select(Job.id).where(Job.revision_id == Revision.id, Job.state == JobState.done)
    walking = set(
        session.scalars(
            text(
                "SELECT objid FROM pg_locks WHERE locktype = 'advisory' AND granted "
                "AND classid = :key AND objsubid = 2 AND database = "
                "(SELECT oid FROM pg_database WHERE datname = current_database())"
            ),
            {"key": WALK_LOCK},
        )
    )
    found: dict[int, list[int]] = {}
    for component_id, revision_id in session.execute(
        select(Revision.component_id, Revision.id)
        .where(Revision.analyzed_at.is_(None), ingested.exists())
        .where(last_moved.between(now - SWEEP_WITHIN, now - LOST_GRACE))
        .where(Revision.component_id.not_in(walking))  # before the limit, not after it
        .order_by(Revision.component_id, *revision_place())
        .limit(limit)
    ):
        found.setdefault(component_id, []).append(revision_id)
    return list(found.values())


def untold_runtime_alarms(session: Session, now: datetime | None = None) -> list[int]:
    """Run-time alarms (of the last `SWEEP_WITHIN`, `SWEEP_GRACE` ago at least) that no alert
    was made of although a subscription listens: their task was never queued (the broker was
    down when `redline watch` reported) or got lost. `runtime_alerts` decides who is told."""
    now = now or utcnow()
    told = select(Alert.id).where(Alert.runtime_alarm_id == RuntimeAlarm.id)
    listening = select(Subscription.id).where(
        *runtime_listeners(RuntimeAlarm.component_id, RuntimeAlarm.at)
    )
    return list(
        session.scalars(
            select(RuntimeAlarm.id)
            .where(RuntimeAlarm.at.between(now - SWEEP_WITHIN, now - SWEEP_GRACE))
            .where(~told.exists(), listening.exists())
            .order_by(RuntimeAlarm.id)
        )
    )
