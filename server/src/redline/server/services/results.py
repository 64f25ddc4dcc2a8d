"""What the measurements say: per-revision points of every series, and detected changes."""

from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import dataclass

from redline.recording import SeriesKey
from redline.recording.format import HOST_PROCESS
from redline.server.models import Change, Execution, Revision, Series, Summary
from redline.server.schemas import ChangeOut, SeriesOut, SeriesPoint, SeriesRef
from redline.server.services.components import get_component
from sqlalchemy import select
from sqlalchemy.orm import Session, aliased


@dataclass
class _Pool:
    """Pools per-execution summaries (n, mean, std) into one revision's n, mean, std."""

    n: int = 0
    total: float = 0.0
    squares: float = 0.0

    def add(self, n: int, mean: float, std: float) -> None:
        self.n += n
        self.total += n * mean
        self.squares += n * (std * std + mean * mean)

    def point(self, revision: Revision) -> SeriesPoint:
        mean = self.total / self.n
        variance = max(self.squares / self.n - mean * mean, 0.0)
        return SeriesPoint(
            revision=revision.title,
            sort_key=revision.sort_key,
            n=self.n,
            mean=mean,
            std=math.sqrt(variance),
        )


def series_ref(series: Series) -> SeriesRef:
    label = SeriesKey(
        series.case, series.phase, series.params, series.process, series.counter
    ).label()
    return SeriesRef(
        id=series.id,
        label=label,
        case=series.case,
        phase=series.phase,
        params=json.loads(series.params),
        process=series.process,
        counter=series.counter,
    )


def component_series(session: Session, component_name: str) -> list[SeriesOut]:
    """Each series of the component with one point per revision, in sort-key order."""
    component = get_component(session, component_name)
    rows = session.execute(
        select(Series, Revision, Summary.n, Summary.mean, Summary.std)
        .join(Summary, Summary.series_id == Series.id)
        .join(Execution, Execution.id == Summary.execution_id)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(Series.component_id == component.id)
        .order_by(
            Series.process == HOST_PROCESS,  # the component's series first, then context
            Series.case,
            Series.phase,
            Series.params,
            Series.process,
            Series.counter,
            Revision.order_key,
            Revision.id,
        )
    )
    pools: dict[Series, dict[Revision, _Pool]] = defaultdict(dict)
    for series, revision, n, mean, std in rows:
        pools[series].setdefault(revision, _Pool()).add(n, mean, std)
    return [
        SeriesOut(
            **series_ref(series).model_dump(),
            points=[pool.point(revision) for revision, pool in by_revision.items()],
        )
        for series, by_revision in pools.items()
    ]


def component_changes(
    session: Session, component_name: str, flagged_only: bool = False
) -> list[ChangeOut]:
    """Detected changes of the component, newest revision first, flagged ones first within it."""
    component = get_component(session, component_name)
    baseline = aliased(Revision)
    query = (
        select(Change, Series, Revision.title, baseline.title)
        .join(Series, Series.id == Change.series_id)
        .join(Revision, Revision.id == Change.revision_id)
        .join(baseline, baseline.id == Change.baseline_revision_id)
        .where(Series.component_id == component.id)
        .order_by(Revision.order_key.desc(), Change.flagged.desc(), Change.p_value, Series.id)
    )
    if flagged_only:
        query = query.where(Change.flagged)
    return [
        ChangeOut(
            series=series_ref(series),
            revision=title,
            baseline=base,
            method=change.method,
            score=change.score,
            p_value=change.p_value,
            effect=change.effect if math.isfinite(change.effect) else None,
            flagged=change.flagged,
            created=change.created,
        )
        for change, series, title, base in session.execute(query)
    ]
