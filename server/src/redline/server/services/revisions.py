"""Revisions and their jobs: created by CI, ordered by an explicit sort key; their state, lists,
detail and verdict text (CI's report of one, one commit under two titles: `revision_reports`)."""

from __future__ import annotations

import base64
import re
from collections import Counter
from typing import Any

from redline.recording.format import META_RUN
from redline.server.db import lock_component
from redline.server.models import (
    DID_NOT_RUN,
    UNENDED,
    Component,
    Execution,
    Job,
    JobState,
    Revision,
    revision_place,
)
from redline.server.schemas.revisions import (
    ExecutionOut,
    JobOut,
    RevisionCreate,
    RevisionDetail,
    RevisionOut,
)
from redline.server.services.components import get_component, get_revision
from redline.server.services.errors import BadRequest, Conflict, Forbidden
from redline.server.services.fresh_runs import mark_waiting
from redline.server.services.repos import repo_key
from redline.server.services.revision_summaries import revision_verdicts
from sqlalchemy import literal, or_, select, tuple_
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, selectinload

_DIGITS = re.compile(r"\d+")
#: the reason of the jobs `cancel_revision` cancels
CANCELLED = "cancelled"


def order_key(sort_key: str) -> str:
    """``sort_key`` in natural order: every digit run (of any script's decimal digits, as ASCII)
    prefixed by its length, so text order is numeric order, the rest compared as text.

    "9" -> "019", "10" -> "0210": compared bytewise, "9" < "10", "r2" < "r10", "1.9" < "1.10"
    (as versions), and "١٠" (Arabic-Indic ten) == "10". A run of 99 digits or more is prefixed
    "99" and its length in three digits, after every shorter run. Titles are never parsed; only
    the sort key the caller gave is normalized. Not a number parser: "1e3" is 1, "e", 3, and
    "-5" is "-" then 5 (docs/api.md).
    """

    def run(match: re.Match[str]) -> str:
        digits = str(int(match.group()))  # int() reads every script's decimal digits
        size = len(digits)
        return f"{size:02d}{digits}" if size < 99 else f"99{size:03d}{digits}"

    return _DIGITS.sub(run, sort_key)


def new_revision(component: Component, data: RevisionCreate) -> Revision:
    """An unsaved revision with one queued job per execution, for the component's host pool.

    Its code comes from the component's own repository, whatever the request says.
    """
    return Revision(
        component=component,
        title=data.title,
        sort_key=data.sort_key,
        order_key=order_key(data.sort_key),
        commit=data.commit,
        repo=component.repo,
        branch=data.branch or component.branch,
        message=data.message,
        committed_at=data.committed_at,
        jobs=[
            Job(execution_index=index, labels=list(component.host_labels or []))
            for index in range(component.executions)
        ],
    )


def require_own_repository(component: Component, data: RevisionCreate) -> None:
    """Forbidden when a report names another repository than the component's."""
    if data.repo and repo_key(data.repo) != component.repo_key:
        raise Forbidden(
            f"a revision of {component.name!r} runs the component's own repository "
            f"({component.repo or 'none set'}), not {data.repo[:200]!r}; only an admin changes "
            f"where its code comes from (PATCH /api/v1/components/{component.name})"
        )


def create_revision(session: Session, data: RevisionCreate) -> Revision:
    """A revision and one queued job per execution the component asks for."""
    component = get_component(session, data.component)
    require_own_repository(component, data)
    revision = new_revision(component, data)
    session.add(revision)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        get_component(session, data.component)  # NotFound when it was deleted meanwhile
        raise Conflict(
            f"component {data.component!r} already has a revision {data.title!r}"
        ) from None
    return revision


def own_jobs(revision: Revision) -> list[Job]:
    """The jobs a revision's state is made of: its own executions, and fresh runs of them
    (`redline.worker.remeasure`) unless those failed: a fresh run that could not be made leaves
    the revision with the runs it had. Confirmation runs never count."""
    return [
        job
        for job in revision.jobs
        if job.pair == 0 and not (job.remeasures_job_id is not None and job.state in DID_NOT_RUN)
    ]


def revision_state(states: list[JobState], analyzed: bool = True) -> str:
    """One word for a revision from its jobs' states.

    ``queued`` while no job has started, ``running`` while any job is under way, then ``failed``
    if any job failed, ``cancelled`` if all were, ``analyzing`` until detection has seen the
    ingested results, else ``done``.
    """
    counts = Counter(states)
    if not states:
        return "empty"
    if counts[JobState.queued] == len(states):
        return "queued"
    if any(counts[state] for state in UNENDED):
        return "running"
    if counts[JobState.failed]:
        return "failed"
    if counts[JobState.cancelled] == len(states):
        return "cancelled"
    return "done" if analyzed else "analyzing"


def _revision_out(revision: Revision) -> dict:
    return dict(
        id=revision.id,
        title=revision.title,
        sort_key=revision.sort_key,
        commit=revision.commit,
        measured_commit=revision.measured_commit,
        repo=revision.repo,
        branch=revision.branch,
        message=revision.message,
        subject=revision.subject,
        committed_at=revision.committed_at,
        created=revision.created,
        analyzed_at=revision.analyzed_at,
        state=revision_state(
            [job.state for job in own_jobs(revision)], analyzed=revision.analyzed_at is not None
        ),
    )


def encode_cursor(revision: Revision) -> str:
    """An opaque position after ``revision`` in sort-key order."""
    raw = f"{revision.order_key}\x00{revision.id}".encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def _decode_cursor(cursor: str) -> tuple[str, int]:
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode()
        key, _, ident = raw.rpartition("\x00")
        return key, int(ident)
    except (ValueError, UnicodeDecodeError):
        raise BadRequest(
            f"malformed cursor {cursor!r}; pass back the X-Next-Cursor header of the last page"
        ) from None


def list_revisions(
    session: Session, component_name: str, limit: int | None = None, cursor: str | None = None
) -> list[RevisionOut]:
    """Revisions in sort-key order; ``limit`` of them after ``cursor`` when given."""
    return [revision_out(r) for r in page_revisions(session, component_name, limit, cursor)]


def newest_revisions(session: Session, component_name: str, limit: int) -> list[RevisionOut]:
    """The component's ``limit`` last revisions in sort-key order, the last first."""
    return [revision_out(revision) for revision in _newest(session, component_name, limit)]


def newest_with_verdicts(
    session: Session, component_name: str, limit: int
) -> tuple[list[RevisionOut], dict[str, str]]:
    """`newest_revisions` and what each one's verdict says (`verdicts_of`), from one read."""
    newest = _newest(session, component_name, limit)
    return [revision_out(r) for r in newest], verdicts_of(session, component_name, newest)


def _newest(session: Session, component_name: str, limit: int) -> list[Revision]:
    component = get_component(session, component_name)
    query = (
        select(Revision)
        .where(Revision.component_id == component.id)
        .order_by(Revision.order_key.desc(), Revision.id.desc())
        .options(selectinload(Revision.jobs))
        .limit(limit)
    )
    return list(session.scalars(query))


def verdicts_of(session: Session, component_name: str, revisions: list[Revision]) -> dict[str, str]:
    """Per revision (its jobs loaded) that has one, its verdict in a few words: what its alarm
    method said (`revision_verdicts`), or why none will come, its jobs failed or cancelled (a
    trial's failed first commit had an empty cell on the component page)."""
    said = revision_verdicts(session, component_name, [r.title for r in revisions])
    found = {r.title: _so_far(r, said.get(r.title)) or _unmeasured(own_jobs(r)) for r in revisions}
    return {title: words for title, words in found.items() if words}


def _so_far(revision: Revision, said: str | None) -> str:
    """``said`` of a revision whose runs are not all in yet, saying so: a trial's row read
    "running | no change in the 25 series judged" with one of its three runs still to come,
    as final as any."""
    jobs = own_jobs(revision)
    coming = sum(job.state in UNENDED for job in jobs)
    if not said or not coming:
        return said or ""
    return f"so far, {len(jobs) - coming} of its {len(jobs)} runs in: {said}"


def revision_out(revision: Revision) -> RevisionOut:
    return RevisionOut(**_revision_out(revision))


def page_revisions(
    session: Session, component_name: str, limit: int | None, cursor: str | None
) -> list[Revision]:
    component = get_component(session, component_name)
    query = (
        select(Revision)
        .where(Revision.component_id == component.id)
        .order_by(Revision.order_key, Revision.id)
        .options(selectinload(Revision.jobs))
    )
    if cursor:
        key, ident = _decode_cursor(cursor)
        query = query.where(
            revision_place() > tuple_(literal(key, Revision.order_key.type), literal(ident))
        )
    if limit is not None:
        query = query.limit(limit)
    return list(session.scalars(query))


def job_out(job: Job) -> JobOut:
    execution = ExecutionOut.model_validate(job.execution) if job.execution else None
    return JobOut(
        id=job.id,
        execution_index=job.execution_index,
        state=job.state.value,
        attempts=job.attempts,
        reason=job.reason,
        host=job.host.name if job.host else None,
        lease_expires_at=job.lease_expires_at,
        execution=execution,
        pair=job.pair,
        confirms=job.confirms_revision.title if job.confirms_revision else None,
        not_before=job.not_before,
    )


UNFINISHED = (JobState.queued, JobState.leased, JobState.running)


def cancel_revision(session: Session, component_name: str, title: str) -> RevisionDetail:
    """Cancel the revision's unfinished jobs, its confirmation runs' too (the baseline's runs
    beside it included), for a superseded commit, say: none is leased again,
    and an agent running one learns it at its next heartbeat (409) and abandons it. Jobs
    already uploaded or finished keep their results."""
    revision = get_revision(session, get_component(session, component_name), title, exact=True)
    lock_component(session, revision.component_id)  # before its jobs' rows: `mark_waiting`
    jobs = session.scalars(
        select(Job)
        .where(
            or_(Job.revision_id == revision.id, Job.confirms_revision_id == revision.id),
            Job.state.in_(UNFINISHED),
        )
        .with_for_update()
    )
    for job in jobs:
        job.state, job.reason = JobState.cancelled, CANCELLED
        if job.remeasures_job_id is not None:  # the sweep has those that waited judged
            mark_waiting(session, job.revision_id)
    session.commit()
    return revision_detail(session, component_name, title)


def _unmeasured(jobs: list[Job]) -> str:
    """The verdict of a revision none will come for, as its jobs failed or were cancelled, and
    why; "" while one may still come (a trial's failed revision read "no verdict yet")."""
    state = revision_state([job.state for job in jobs])
    failed = [job for job in jobs if job.state == JobState.failed]
    if state == "failed":
        reasons = "; ".join(dict.fromkeys(job.reason or "no reason given" for job in failed))
        return f"no verdict: the revision failed, {len(failed)} of its {len(jobs)} jobs ({reasons})"
    return "no verdict: its jobs were cancelled" if state == "cancelled" else ""


def revision_detail(session: Session, component_name: str, title: str) -> RevisionDetail:
    component = get_component(session, component_name)
    found = get_revision(session, component, title)  # by its title, or its commit's hash
    revision = session.scalars(
        select(Revision)
        .where(Revision.id == found.id)
        .options(
            selectinload(Revision.jobs).selectinload(Job.execution),
            selectinload(Revision.jobs).selectinload(Job.host),
        )
    ).one()
    return RevisionDetail(
        **_revision_out(revision),
        component=component.name,
        jobs=[job_out(job) for job in revision.jobs],
        verdict=verdicts_of(session, component_name, [revision]).get(revision.title, ""),
    )


def execution_notes(session: Session, revision_id: int) -> dict[int, str]:
    """Per execution of the revision, what its run's metadata says went unusually (`run_note`),
    for the executions with something to say."""
    notes = {
        ident: run_note((meta or {}).get(META_RUN) or {})
        for ident, meta in session.execute(
            select(Execution.id, Execution.meta).where(Execution.revision_id == revision_id)
        )
    }
    return {ident: note for ident, note in notes.items() if note}


def run_note(run: dict[str, Any]) -> str:
    """What a run's metadata says went unusually: runs the agent repeated because another load
    disturbed them, a status other than "ok" (a run stopped, or the component took no part), a
    warning; "" for a run that went as it should."""
    said = []
    if run.get("disturbed_runs"):
        said.append(
            f"run again {run['disturbed_runs']} time(s), the host being busy "
            f"({run.get('disturbed_reason', '')})"
        )
    status, warning = str(run.get("status") or "ok"), str(run.get("warning") or "")
    said += [": ".join(part for part in (status if status != "ok" else "", warning) if part)]
    return "; ".join(part for part in said if part)
