"""The read API: filtered series, a series' per-execution summaries, one execution's details."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any, Protocol
from urllib.parse import quote

from redline.server.models import Component, Execution, Job, Revision, Series, Summary
from redline.server.schemas.results import (
    ExecutionDetail,
    SeriesDetail,
    SeriesOut,
    SummaryOut,
)
from redline.server.services.errors import NotFound
from redline.server.services.results import series_ref
from sqlalchemy import func, select
from sqlalchemy.orm import Session, selectinload

FIELDS = ("case", "phase", "process", "counter")


class Identified(Protocol):
    """What a filter reads of a series: `SeriesRef`, or a page's lighter `Identity`."""

    @property
    def case(self) -> str: ...
    @property
    def phase(self) -> str: ...
    @property
    def process(self) -> str: ...
    @property
    def counter(self) -> str: ...
    @property
    def params(self) -> Mapping[str, Any]: ...


def matches(series: Identified, fields: dict[str, str | None], params: dict[str, str]) -> bool:
    """Whether the series has these field values and parameter values (compared as text)."""
    if any(value is not None and getattr(series, name) != value for name, value in fields.items()):
        return False
    return all(
        name in series.params and param_text(series.params[name]) == value
        for name, value in params.items()
    )


def revision_page(component: str, title: str) -> str:
    """The path of a revision's page."""
    return f"/components/{quote(component)}/revisions/{quote(title)}"


def param_text(value: object) -> str:
    """A parameter value as the filters compare it: text as is, anything else as JSON."""
    return value if isinstance(value, str) else json.dumps(value)


def filter_series(
    items: list[SeriesOut], fields: dict[str, str | None], params: dict[str, str]
) -> list[SeriesOut]:
    return [item for item in items if matches(item, fields, params)]


def series_detail(session: Session, series_id: int) -> SeriesDetail:
    """The series and every execution's summary of it, in sort-key order."""
    series = session.get(Series, series_id)
    if series is None:
        raise NotFound(f"unknown series {series_id}")
    # plain columns validated in one call: 2,000 ORM objects were most of a 1,000-point series
    rows = session.execute(
        select(Revision.title.label("revision"), Revision.sort_key, *_SUMMARY_COLUMNS)
        .join(Execution, Execution.id == Summary.execution_id)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(Summary.series_id == series_id)
        .order_by(Revision.order_key, Revision.id, Execution.id)
    ).mappings()
    name = session.scalar(select(Component.name).where(Component.id == series.component_id))
    return SeriesDetail.model_validate(
        {
            **series_ref(series).model_dump(),
            "component": name or "",
            "summaries": [dict(row) for row in rows],
        }
    )


_SUMMARY_COLUMNS = [
    getattr(Summary, field)
    for field in SummaryOut.model_fields
    if field not in ("revision", "sort_key")
]


def execution_detail(session: Session, execution_id: int) -> ExecutionDetail:
    execution = session.scalar(
        select(Execution)
        .where(Execution.id == execution_id)
        .options(
            selectinload(Execution.job).selectinload(Job.host),
            selectinload(Execution.job).selectinload(Job.revision).selectinload(Revision.component),
        )
    )
    if execution is None:
        raise NotFound(f"unknown execution {execution_id}")
    job, revision = execution.job, execution.job.revision
    count = session.scalar(
        select(func.count()).select_from(Summary).where(Summary.execution_id == execution_id)
    )
    return ExecutionDetail(
        id=execution.id,
        component=revision.component.name,
        revision=revision.title,
        sort_key=revision.sort_key,
        job_id=job.id,
        execution_index=job.execution_index,
        host=job.host.name if job.host else None,
        sha256=execution.sha256,
        size=execution.size,
        created=execution.created,
        metadata=execution.meta,
        recording_pruned_at=execution.pruned_at,
        series=count or 0,
    )
