"""The agent side of jobs: hosts register, lease a job, keep it alive, or give it up."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timedelta

from redline.detect.confirmation import SUSPECTED
from redline.detect.result import NOT_ENOUGH_DATA
from redline.server.models import (
    Component,
    Detection,
    Host,
    Job,
    JobState,
    Revision,
    revision_place,
    utcnow,
)
from redline.server.schemas.jobs import LeasedJob, LeasedRevision, RegisterRequest
from redline.server.services.errors import Conflict, NotFound
from sqlalchemy import ColumnElement, and_, case, cast, or_, select, tuple_, update
from sqlalchemy.dialects.postgresql import JSONB, insert
from sqlalchemy.orm import Session, aliased

HELD = (JobState.leased, JobState.running)
#: jobs that have not ended: their revision's verdict may still change
UNENDED = (JobState.queued, *HELD, JobState.uploaded)


def register_host(session: Session, data: RegisterRequest) -> Host:
    """Create the host or refresh its fingerprint and labels (registering again is fine; two
    agents registering one name at once both succeed: INSERT ... ON CONFLICT DO UPDATE)."""
    fields = dict(fingerprint=data.fingerprint, labels=data.labels, last_seen=utcnow())
    host_id = session.scalar(
        insert(Host)
        .values(name=data.name, **fields)
        .on_conflict_do_update(index_elements=["name"], set_=fields)
        .returning(Host.id)
    )
    session.commit()
    return session.get_one(Host, host_id, populate_existing=True)


def _host(session: Session, name: str) -> Host:
    host = session.scalar(select(Host).where(Host.name == name))
    if host is None:
        raise NotFound(f"unknown host {name!r}; register it first")
    return host


def _fail_exhausted(session: Session, now: datetime, max_attempts: int) -> None:
    """Jobs whose lease lapsed ``max_attempts`` times are failed instead of handed out again."""
    session.execute(
        update(Job)
        .where(Job.state.in_(HELD), Job.lease_expires_at < now, Job.attempts >= max_attempts)
        .values(
            state=JobState.failed,
            lease_expires_at=None,
            updated=now,
            reason=f"lease expired {max_attempts} times without a recording",
        )
    )


#: how recent a component's mark may be left: the turns need no finer grain (jobs take
#: minutes), and a storm of leases of one component then writes its row once a second, not
#: once a lease (bench_scale, one run each: 20 agents on 2 API processes leased 84/s with a
#: write a lease, 89/s with this grain, 99/s before the turns)
SERVED_GRAIN = timedelta(seconds=1)


def _served(session: Session, component_id: int, now: datetime) -> None:
    """Mark the component served at ``now`` for `lease_job`'s turns, unless it was marked in
    the last `SERVED_GRAIN` or an agent leasing at the same moment holds its row (it is marking
    it just as recently): agents of one component never queue behind each other on that row."""
    row = select(Component).where(
        Component.id == component_id,
        or_(
            Component.last_leased_at.is_(None),
            Component.last_leased_at < now - SERVED_GRAIN,
        ),
    )
    component = session.scalar(row.with_for_update(skip_locked=True))
    if component is not None:
        component.last_leased_at = now


def lease_job(
    session: Session, host_name: str, lease_seconds: int, max_attempts: int
) -> Job | None:
    """Hand the host the next queued (or abandoned) job whose pool it is in (it has every label
    the job asks for); None when there is none.

    Confirmation and re-measuring runs go first, in the order they were queued. Other jobs go
    to the component served longest ago (``last_leased_at``; never served first), and within
    it to the newest revision, newest meaning most recently reported (sort keys of different
    components do not compare): a component whose CI reports faster than the hosts run does
    not starve the others, one job each in turn.
    ``FOR UPDATE SKIP LOCKED``: agents leasing at once never get the same job, nor wait.
    """
    host = _host(session, host_name)
    now = utcnow()
    _fail_exhausted(session, now, max_attempts)
    available = or_(
        Job.state == JobState.queued,
        and_(Job.state.in_(HELD), Job.lease_expires_at < now),
    )
    in_pool = cast(Job.labels, JSONB).contained_by(list(host.labels or []))  # has every label
    # a confirmation run goes to the host that measured the revision it confirms, and its pairs
    # go in the order they were queued (baseline, candidate, baseline, ...) before other work;
    # so does a fresh run of a disturbed execution, which a later revision's verdict may await
    pinned = or_(Job.pinned_host_id.is_(None), Job.pinned_host_id == host.id)
    ahead = or_(Job.confirms_revision_id.is_not(None), Job.remeasures_job_id.is_not(None))
    job = session.scalar(
        select(Job)
        .join(Revision, Revision.id == Job.revision_id)
        .join(Component, Component.id == Revision.component_id)
        .where(available, in_pool, pinned, _pair_may_start())
        .order_by(
            case((ahead, 0), else_=1),
            case((ahead, Job.id), else_=0),
            Component.last_leased_at.asc().nulls_first(),
            Revision.id.desc(),
            Job.execution_index,
        )
        .limit(1)
        .with_for_update(skip_locked=True, of=Job)
    )
    host.last_seen = now
    if job is not None:
        job.state = JobState.leased
        job.host = host
        job.attempts += 1
        job.lease_expires_at = now + timedelta(seconds=lease_seconds)
        _served(session, job.revision.component_id, now)
    session.commit()
    return job


def current_pairs(jobs: Sequence[Job], candidate_id: int) -> tuple[int | None, list[Job]]:
    """The baseline of a revision's newest confirmation pairs and the jobs of the pairs queued
    against it since the last against another ((None, []) without pairs). The pairs are queued
    once per baseline (`redline.worker.confirm_runs`): those before were queued before the
    revision was judged again, a revision that arrived late having become its baseline, and
    measure another comparison (also when the baseline went back to an earlier one)."""
    baseline_of = {job.pair: job.revision_id for job in jobs if job.revision_id != candidate_id}
    if not baseline_of:
        return None, []
    baseline = baseline_of[max(baseline_of)]
    cut = max((pair for pair, of in baseline_of.items() if of != baseline), default=0)
    return baseline, [job for job in jobs if job.pair > cut]


def _pair_may_start() -> ColumnElement[bool]:
    """A confirmation pair after the first starts once the pairs before it have ended and been
    judged (the revision it confirms analysed since): those may decide every change, and then
    it is cancelled as not needed instead of run. Leased as soon as queued, the third pair's
    baseline run was under way when the second pair decided, a run for nothing (issue 12's
    cost; the demo ran 5 confirmation runs where 4 decided)."""
    earlier = aliased(Job)
    confirmed = aliased(Revision)
    unended = (
        select(earlier.id)
        .where(
            earlier.confirms_revision_id == Job.confirms_revision_id,
            earlier.pair < Job.pair,
            earlier.state.in_(UNENDED),
        )
        .exists()
    )
    judged = (
        select(confirmed.id)
        .where(confirmed.id == Job.confirms_revision_id, confirmed.analyzed_at.is_not(None))
        .exists()
    )
    return or_(Job.confirms_revision_id.is_(None), Job.pair <= 1, and_(~unended, judged))


def leased_job(job: Job) -> LeasedJob:
    revision = job.revision
    assert job.lease_expires_at is not None
    return LeasedJob(
        # the component's repository as an admin set it, never one stored with the revision
        id=job.id,
        component=revision.component.name,
        repo=revision.component.repo,
        commit=revision.commit,
        suite=revision.component.suite,
        revision=LeasedRevision(title=revision.title, sort_key=revision.sort_key),
        execution_index=job.execution_index,
        lease_expires_at=job.lease_expires_at,
        cases=list(job.cases or []),
        parameter_sets=dict(job.parameter_sets or {}),
    )


def _locked_job(session: Session, job_id: int) -> Job:
    job = session.scalar(select(Job).where(Job.id == job_id).with_for_update())
    if job is None:
        raise NotFound(f"unknown job {job_id}")
    return job


def holder(job: Job) -> str | None:
    """The name of the host the job was last leased to."""
    return job.host.name if job.host else None


def ensure_held(job: Job, host_name: str) -> None:
    """Conflict unless ``host_name`` holds the job now (a lapsed host's job may be re-leased)."""
    if job.state not in HELD or holder(job) != host_name:
        raise Conflict(
            f"job {job.id} is not leased to host {host_name!r} "
            f"(state {job.state.value}, host {holder(job)!r})"
        )


def heartbeat(session: Session, job_id: int, host_name: str, lease_seconds: int) -> Job:
    """Extend the lease of a job this host holds; the first heartbeat marks it running."""
    job = _locked_job(session, job_id)
    ensure_held(job, host_name)
    now = utcnow()
    job.state = JobState.running
    job.lease_expires_at = now + timedelta(seconds=lease_seconds)
    assert job.host is not None
    job.host.last_seen = now
    session.commit()
    return job


def release_job(session: Session, job_id: int, host_name: str) -> Job:
    """Give a held job back to the queue without counting the attempt (an agent stopping)."""
    job = _locked_job(session, job_id)
    ensure_held(job, host_name)
    job.state, job.host, job.lease_expires_at = JobState.queued, None, None
    job.attempts = max(0, job.attempts - 1)
    session.commit()
    return job


def ended(session: Session, revision_id: int) -> bool:
    """Whether every job of the revision has ended (none queued, held or awaiting ingest)."""
    return not session.scalar(
        select(
            select(Job.id)
            .where(Job.revision_id == revision_id)
            .where(Job.state.in_(UNENDED))
            .exists()
        )
    )


def fail_job(session: Session, job_id: int, host_name: str, reason: str) -> Job:
    """Mark a job this host holds failed with its reason; the same host failing it again
    changes nothing. Another host (one whose lease lapsed, say) gets a Conflict."""
    job = _locked_job(session, job_id)
    if job.state == JobState.failed and holder(job) == host_name:
        session.commit()
        return job
    ensure_held(job, host_name)
    job.state = JobState.failed
    job.reason = reason
    job.lease_expires_at = None
    session.commit()
    return job


#: a job in these states ended without a recording: no ingest follows it
DID_NOT_RUN = (JobState.failed, JobState.cancelled)
#: a job in these states runs no more
FINISHED = (JobState.done, *DID_NOT_RUN)


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


def fresh_run_ended_unjudged(
    session: Session, revision: Revision, baselines: Sequence[int | None]
) -> str | None:
    """The title of a revision in the same span whose fresh run ended without a recording (its
    build failed, its leases lapsed, it was cancelled) after ``revision`` was last judged:
    ``revision`` is judged again and its confirmation runs queued once the worker hears of it
    (`judged_again`), and until then its suspected change is no verdict yet."""
    span = _span(session, revision, baselines)
    if span is None or revision.analyzed_at is None:
        return None
    return session.scalar(
        select(Revision.title)
        .join(Job, Job.revision_id == Revision.id)
        .where(
            Revision.component_id == revision.component_id,
            span,
            Job.remeasures_job_id.is_not(None),
            Job.state.in_(DID_NOT_RUN),
            Job.updated > revision.analyzed_at,
        )
        .limit(1)
    )


def waiting_on(session: Session, revision_id: int) -> list[int]:
    """The revisions judged again once this one's fresh run has ended: those whose "not
    enough data" verdicts name it as their baseline, and those with a suspected change whose
    span (baseline, revision) holds it (`redline.worker.remeasure.busy_between`), however far
    after it they are."""
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
    return list(session.scalars(lacking.union(spanning)))


def judged_again(session: Session, job: Job) -> list[int]:
    """What to judge once ``job`` has ended without a recording, in order: for a fresh run,
    its revision and those that waited for it (`waiting_on`), which may now be judged
    without it; nothing for any other job."""
    if job.remeasures_job_id is None or job.state not in DID_NOT_RUN:
        return []
    return [job.revision_id, *waiting_on(session, job.revision_id)]
