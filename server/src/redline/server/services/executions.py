"""A component's executions, newest revision first: the API's paged list
(``GET /api/v1/components/{name}/executions``), the component page's newest ones and the
executions page, filtered by revision, host and job state; and what a run's metadata says of
its duration."""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from redline.recording.format import META_RUN
from redline.server.models import Component, Execution, Host, Job, JobState, Revision
from redline.server.schemas.results import ExecutionListed
from redline.server.services.components import get_component, get_revision
from redline.server.services.errors import BadRequest, NotFound
from redline.server.services.paging import decode_cursor, encode_cursor
from sqlalchemy import Row, Select, literal, select, tuple_
from sqlalchemy.orm import Session

#: what the agent's run metadata and an LNT report call the run's start and end
_TIMES = ((META_RUN, "started_at", "ended_at"), (None, "start_time", "end_time"))


def _moment(value: object) -> datetime | None:
    try:
        found = datetime.fromisoformat(str(value))
    except ValueError:
        return None
    return found if found.tzinfo is not None else found.replace(tzinfo=UTC)


def run_seconds(meta: Mapping[str, Any] | None) -> float | None:
    """How long the run took by its own metadata (the agent's ``started_at`` to ``ended_at``,
    an LNT report's ``start_time`` to ``end_time``); None when it does not say."""
    for section, start, end in _TIMES:
        where = (meta or {}).get(section) if section else meta
        if not isinstance(where, Mapping) or not where.get(start) or not where.get(end):
            continue
        began, ended = _moment(where[start]), _moment(where[end])
        if began is not None and ended is not None and ended >= began:
            return (ended - began).total_seconds()
    return None


#: an execution as listed: it, its job, its revision's title, sort and order keys, its host
Listed = tuple[Execution, Job, str, str, str, str | None]


def _query(component: Component) -> Select[*Listed]:
    return (
        select(Execution, Job, Revision.title, Revision.sort_key, Revision.order_key, Host.name)
        .join(Job, Job.id == Execution.job_id)
        .join(Revision, Revision.id == Execution.revision_id)
        .outerjoin(Host, Host.id == Job.host_id)
        .where(Revision.component_id == component.id)
        .order_by(Revision.order_key.desc(), Execution.id.desc())
    )


def _listed(row: Row[*Listed]) -> ExecutionListed:
    execution, job, title, sort_key, _, host = row
    return ExecutionListed(
        id=execution.id,
        revision=title,
        sort_key=sort_key,
        job_id=job.id,
        execution_index=job.execution_index,
        pair=job.pair,
        host=host,
        state=job.state.value,
        created=execution.created,
        duration_s=run_seconds(execution.meta),
        size=execution.size,
        recording_pruned_at=execution.pruned_at,
    )


def list_executions(
    session: Session,
    component_name: str,
    revision: str | None = None,
    host: str | None = None,
    state: str | None = None,
    limit: int | None = None,
    cursor: str | None = None,
) -> tuple[list[ExecutionListed], str | None]:
    """The component's executions (its revisions' own and confirmation runs), newest revision
    first, the newest execution first within it; ``revision`` (a title), ``host`` (a name) and
    ``state`` (the job's) filter, an unknown revision or host is a `NotFound` naming it;
    ``limit`` of them after ``cursor``, and the next page's cursor (None after the last)."""
    component = get_component(session, component_name)
    query = _query(component)
    if revision is not None:
        query = query.where(Revision.id == get_revision(session, component, revision).id)
    if host is not None:
        if session.scalar(select(Host.id).where(Host.name == host)) is None:
            raise NotFound(f"no performance host {host!r}")
        query = query.where(Host.name == host)
    if state is not None:
        if state not in JobState.__members__:
            raise BadRequest(f"state: one of {', '.join(JobState.__members__)}, not {state!r}")
        query = query.where(Job.state == JobState(state))
    if cursor:
        key, last = decode_cursor(cursor, str, int)
        query = query.where(
            tuple_(Revision.order_key, Execution.id)
            < tuple_(literal(key, Revision.order_key.type), literal(last))
        )
    rows = list(session.execute(query.limit(limit)))
    following = None
    if limit is not None and len(rows) == limit:
        following = encode_cursor(rows[-1][4], rows[-1][0].id)
    return [_listed(row) for row in rows], following


def newest_executions(session: Session, component: Component, count: int) -> list[ExecutionListed]:
    """The newest ``count`` executions of the ``count`` newest revisions (one not run yet has
    none), in `list_executions`'s order: the component page's, read from those revisions alone
    so that its cost does not grow with the history."""
    newest = (
        select(Revision.id)
        .where(Revision.component_id == component.id)
        .order_by(Revision.order_key.desc(), Revision.id.desc())
        .limit(count)
    )
    query = _query(component).where(Revision.id.in_(newest.scalar_subquery())).limit(count)
    return [_listed(row) for row in session.execute(query)]


def host_names(session: Session) -> list[str]:
    """Every performance host's name (a handful): what a host filter offers."""
    return list(session.scalars(select(Host.name).order_by(Host.name)))
