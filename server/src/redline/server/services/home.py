"""What the home page shows: every component at a glance, the performance hosts, the job queue."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from redline.recording import HOST_PROCESS, SeriesKey
from redline.recording.driver import DRIVER_PROCESS, RECORDER_PROCESS
from redline.recording.format import OWN_PROCESS
from redline.server.models import (
    Component,
    Execution,
    Host,
    Job,
    JobState,
    Regression,
    Revision,
    Series,
    Summary,
    utcnow,
)
from redline.server.services.components import list_components
from redline.server.services.open_regressions import still_open
from redline.server.services.revisions import newest_revisions
from sqlalchemy import func, select
from sqlalchemy.orm import Session

#: a host that polled within this long is online (agents poll every few seconds)
ONLINE = timedelta(minutes=2)
UNFINISHED = (JobState.queued, JobState.leased, JobState.running)


@dataclass(frozen=True)
class HostView:
    name: str
    online: bool
    busy: str  # "component revision" of the job it holds, or ""
    last_seen: datetime
    labels: list[str]
    fingerprint: dict[str, Any]


@dataclass(frozen=True)
class QueuedJob:
    id: int
    component: str
    revision: str
    state: str
    host: str
    pair: int


#: the fingerprint of a host only imported results name (`redline.server.services.imports`)
IMPORTED = {"imported": True}


def list_hosts(session: Session) -> list[HostView]:
    """The performance hosts: the agents that registered, whether online now or not."""
    held = {
        host_id: f"{component} {title}"
        for host_id, component, title in session.execute(
            select(Job.host_id, Component.name, Revision.title)
            .join(Revision, Revision.id == Job.revision_id)
            .join(Component, Component.id == Revision.component_id)
            .where(Job.state.in_((JobState.leased, JobState.running)))
        )
    }
    now = utcnow()
    return [
        HostView(
            name=host.name,
            online=now - host.last_seen <= ONLINE,
            busy=held.get(host.id, ""),
            last_seen=host.last_seen,
            labels=list(host.labels or []),
            fingerprint=dict(host.fingerprint or {}),
        )
        for host in session.scalars(select(Host).order_by(Host.name))
        if host.fingerprint != IMPORTED  # a machine an import named, not an agent: no host here
    ]


def queue(session: Session, limit: int = 20) -> tuple[dict[str, int], list[QueuedJob]]:
    """How many jobs wait or run, by state, and the first ``limit`` of them in lease order."""
    counts = {
        state.value: number
        for state, number in session.execute(
            select(Job.state, func.count()).where(Job.state.in_(UNFINISHED)).group_by(Job.state)
        )
    }
    rows = session.execute(
        select(Job, Component.name, Revision.title, Host.name)
        .join(Revision, Revision.id == Job.revision_id)
        .join(Component, Component.id == Revision.component_id)
        .outerjoin(Host, Host.id == Job.host_id)
        .where(Job.state.in_(UNFINISHED))
        .order_by(Job.state != JobState.running, Job.state != JobState.leased, Job.id)
        .limit(limit)
    )
    jobs = [
        QueuedJob(job.id, component, title, job.state.value, host or "", job.pair)
        for job, component, title, host in rows
    ]
    return counts, jobs


#: the counter a component's sparkline follows (its first series of it, else its first series)
HEADLINE_COUNTER = "cpu_percent"
SPARKLINE_POINTS = 30


@dataclass(frozen=True)
class Overview:
    """A component as the home page lists it."""

    name: str
    newest: str  # the newest revision's title
    newest_state: str
    open_regressions: int
    headline: str  # the series the sparkline follows
    sparkline: list[float]  # its mean per execution, oldest first


def _headline(session: Session, component_id: int) -> tuple[str, list[float]]:
    series = session.scalar(
        select(Series)
        .where(
            Series.component_id == component_id,
            Series.process.not_in((HOST_PROCESS, OWN_PROCESS, DRIVER_PROCESS, RECORDER_PROCESS)),
        )
        .order_by(Series.counter != HEADLINE_COUNTER, Series.id)
        .limit(1)
    )
    if series is None:
        return "", []
    means = session.scalars(
        select(Summary.mean)
        .join(Execution, Execution.id == Summary.execution_id)
        .join(Job, Job.id == Execution.job_id)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(Summary.series_id == series.id, Job.pair == 0)
        .order_by(Revision.order_key.desc(), Execution.id.desc())
        .limit(SPARKLINE_POINTS)
    )
    label = SeriesKey(series.case, series.phase, series.params, series.process, series.counter)
    return label.label(), list(means)[::-1]


def overview(session: Session) -> list[Overview]:
    """Every component with its newest revision, its open regressions and its sparkline."""
    open_counts: dict[int, int] = {
        component_id: number
        for component_id, number in session.execute(
            select(Regression.component_id, func.count())
            .where(*still_open())
            .group_by(Regression.component_id)
        )
    }
    found = []
    for component in list_components(session):
        newest = newest_revisions(session, component.name, 1)
        headline, sparkline = _headline(session, component.id)
        found.append(
            Overview(
                name=component.name,
                newest=newest[0].title if newest else "",
                newest_state=newest[0].state if newest else "",
                open_regressions=open_counts.get(component.id, 0),
                headline=headline,
                sparkline=sparkline,
            )
        )
    return found
