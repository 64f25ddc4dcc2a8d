"""The agent side of jobs: hosts register, lease a job, keep it alive, or give it up."""

from __future__ import annotations

from collections.abc import Collection, Sequence
from datetime import datetime, timedelta

from redline.server.db import lock_component
from redline.server.models import (
    HELD,
    UNENDED,
    Component,
    Host,
    Job,
    JobState,
    Revision,
    utcnow,
)
from redline.server.schemas.jobs import LeasedJob, LeasedRevision, RegisterRequest
from redline.server.services.errors import Conflict, NotFound
from redline.server.services.fresh_runs import mark_waiting
from redline.server.services.measured_commit import commit_to_run
from sqlalchemy import ColumnElement, and_, case, cast, or_, select, true, update
from sqlalchemy.dialects.postgresql import JSONB, insert
from sqlalchemy.orm import Session, aliased


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
    """Jobs whose lease lapsed ``max_attempts`` times are failed instead of handed out again;
    a fresh run's failure marks the revisions that waited for it (`mark_waiting`), which
    the periodic sweep then has judged. The components of such fresh runs are locked before
    any job's row (`lock_component`)."""
    exhausted = (Job.state.in_(HELD), Job.lease_expires_at < now, Job.attempts >= max_attempts)
    for component_id in session.scalars(
        select(Revision.component_id)
        .join(Job, Job.revision_id == Revision.id)
        .where(*exhausted, Job.remeasures_job_id.is_not(None))
        .distinct()
        .order_by(Revision.component_id)
    ):
        lock_component(session, component_id)
    failed = session.execute(
        update(Job)
        .where(*exhausted)
        .values(
            state=JobState.failed,
            lease_expires_at=None,
            updated=now,
            reason=f"lease expired {max_attempts} times without a recording",
        )
        .returning(Job.revision_id, Job.remeasures_job_id)
    )
    for revision_id, remeasures in failed.all():
        if remeasures is not None:
            mark_waiting(session, revision_id)


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
    session: Session,
    host_name: str,
    lease_seconds: int,
    max_attempts: int,
    allowed: Collection[str] | None = None,
    components: Collection[str] = (),
) -> Job | None:
    """Hand the host the next queued (or abandoned) job whose pool it is in (it has every label
    the job asks for, of those its token was given: ``allowed``, None for any) of the
    ``components`` its token is bound to (none: of any); None when there is none. The host's
    row keeps the labels it registered with, perhaps under a token revoked since, which a token
    given fewer must not lease with.

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
    available = and_(
        or_(Job.state == JobState.queued, and_(Job.state.in_(HELD), Job.lease_expires_at < now)),
        or_(Job.not_before.is_(None), Job.not_before <= now),  # a pair run again after a busy spell
    )
    labels = [label for label in host.labels or [] if allowed is None or label in allowed]
    in_pool = cast(Job.labels, JSONB).contained_by(labels)  # has every label
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
        .where(Component.name.in_(components) if components else true())
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
        commit=commit_to_run(revision),  # the hash its first run measured: a branch moves
        suite=revision.component.suite,
        revision=LeasedRevision(title=revision.title, sort_key=revision.sort_key),
        execution_index=job.execution_index,
        lease_expires_at=job.lease_expires_at,
        cases=list(job.cases or []),
        parameter_sets=dict(job.parameter_sets or {}),
        sets_alone=job.sets_alone,
        busy_matters=job.busy_matters,
    )


def component_of_job(session: Session, job_id: int) -> str | None:
    """The name of the component whose job ``job_id`` is; None when there is no such job."""
    return session.scalar(
        select(Component.name)
        .join(Revision, Revision.component_id == Component.id)
        .join(Job, Job.revision_id == Revision.id)
        .where(Job.id == job_id)
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


def fail_job(
    session: Session, job_id: int, host_name: str, reason: str, of_commit: bool = False
) -> tuple[Job, list[int]]:
    """Mark a job this host holds failed with its reason; the same host failing it again
    changes nothing. Another host (one whose lease lapsed, say) gets a Conflict. Returns the
    job, and for a fresh run others waited for, what to judge now (`mark_waiting`).
    ``of_commit``: the commit's own fault, which every execution of it meets: the revision's
    own executions still queued are cancelled, saying why (its verdict is "failed" whatever
    they would do; a trial's broken suite failed three, one after another)."""
    job = _locked_job(session, job_id)
    if job.state == JobState.failed and holder(job) == host_name:
        session.commit()
        return job, []
    ensure_held(job, host_name)
    job.state = JobState.failed
    job.reason = reason
    job.lease_expires_at = None
    if of_commit and job.pair == 0 and job.remeasures_job_id is None:
        first = reason.strip().splitlines()[0][:300] if reason.strip() else "failed"
        for other in session.scalars(
            select(Job)
            .where(
                Job.revision_id == job.revision_id,
                Job.pair == 0,
                Job.remeasures_job_id.is_(None),  # a fresh run others wait for is theirs to end
                Job.state == JobState.queued,
            )
            .with_for_update(skip_locked=True)  # one a host is leasing now runs, and fails alike
        ):
            other.state = JobState.cancelled
            other.reason = f"not run: job {job.id} of this commit failed so ({first})"
    again = mark_waiting(session, job.revision_id) if job.remeasures_job_id else []
    session.commit()
    return job, again
