"""What the measurements say: per-revision points of every series, and detected changes."""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Collection, Mapping

from redline.detect.config import CHARTED_METHOD
from redline.detect.counters import CONTEXT_COUNTERS, judged, judged_among, kind, worse
from redline.detect.result import NOT_ENOUGH_DATA
from redline.detect.summary import Pooled
from redline.recording import SeriesKey
from redline.recording.format import HOST_PROCESS
from redline.server.models import Detection, Execution, Revision, Series, Summary
from redline.server.schemas.results import ChangeOut, SeriesOut, SeriesPoint, SeriesRef
from redline.server.services.components import get_component
from redline.server.services.detection_config import component_config
from redline.server.services.paging import after_newest_first, encode_cursor
from sqlalchemy import select
from sqlalchemy.orm import Session, aliased


def beside(session: Session, series: Series, counter: str) -> int | None:
    """The id of the series of ``counter`` measured in the same segment as ``series`` (its
    component, test case, phase, parameter set and process), None where there is none: a CPU
    share's per-unit figures, a per-unit figure's CPU time."""
    return session.scalar(
        select(Series.id).where(
            Series.component_id == series.component_id,
            Series.case == series.case,
            Series.phase == series.phase,
            Series.params == series.params,
            Series.process == series.process,
            Series.counter == counter,
        )
    )


def series_ref(
    series: Series,
    context: Collection[str] = CONTEXT_COUNTERS,
    judged_ids: Collection[int] | None = None,
) -> SeriesRef:
    """The series as the API shows it; ``context``: the counters its component does not judge
    (its detection settings' ``context_counters``); ``judged_ids``: the series judged among
    those shown with it (`judged_among`: of a CPU share and its CPU per unit of work, those
    its component's methods judge), None to judge it by its name alone."""
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
        kind=kind(series.process),
        worse=worse(series.process, series.counter),
        judged=judged(series.process, series.counter, context)
        if judged_ids is None
        else series.id in judged_ids,
    )


#: the newest revisions whose points `component_series` gives unless asked for more
SERIES_REVISIONS = 1000


def component_series(
    session: Session,
    component_name: str,
    segment: Mapping[str, str | None] | None = None,
    revisions: int = SERIES_REVISIONS,
) -> list[SeriesOut]:
    """Each series of the component with one point per revision among the newest
    ``revisions``, in sort-key order, of the ``segment`` given (its case, phase and process:
    None, any); whether it is judged as the component's own settings say. The request read
    every point of the whole history into objects before it filtered them (an audit)."""
    component = get_component(session, component_name)
    config = component_config(session, component.id)
    context = config.context_counters
    newest = (
        select(Revision.id)
        .where(Revision.component_id == component.id)
        .order_by(Revision.order_key.desc(), Revision.id.desc())
        .limit(revisions)
    )
    chosen = [
        getattr(Series, name) == value
        for name, value in (segment or {}).items()
        if name in ("case", "phase", "process") and value is not None
    ]  # not the counter: a CPU share is judged by whether its per-unit figure is beside it
    rows = session.execute(
        select(Series, Revision, Summary.n, Summary.mean, Summary.std)
        .join(Summary, Summary.series_id == Series.id)
        .join(Execution, Execution.id == Summary.execution_id)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(Series.component_id == component.id, Revision.id.in_(newest), *chosen)
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
    pools: dict[Series, dict[Revision, Pooled]] = defaultdict(dict)
    for series, revision, n, mean, std in rows:
        pools[series].setdefault(revision, Pooled()).add(n, mean, std)
    judged_ids = {series.id for series in judged_among(pools, context, config.levels)}
    return [
        SeriesOut(
            **series_ref(series, context, judged_ids).model_dump(),
            points=[
                SeriesPoint(
                    revision=revision.title,
                    sort_key=revision.sort_key,
                    n=pool.n,
                    mean=pool.mean,
                    std=pool.std,
                )
                for revision, pool in by_revision.items()
            ],
        )
        for series, by_revision in pools.items()
    ]


def component_changes(
    session: Session,
    component_name: str,
    flagged_only: bool = False,
    limit: int | None = None,
    cursor: str | None = None,
) -> tuple[list[ChangeOut], str | None]:
    """KS's decided verdicts on the component's series, newest revision first, flagged ones
    first within it; ``limit`` of them after ``cursor``, and the cursor of the next page (None
    after the last)."""
    component = get_component(session, component_name)
    baseline = aliased(Revision)
    query = (
        select(Detection, Series, Revision.title, baseline.title)
        .join(Series, Series.id == Detection.series_id)
        .join(Revision, Revision.id == Detection.revision_id)
        .join(baseline, baseline.id == Detection.baseline_revision_id)
        .where(
            Series.component_id == component.id,
            Detection.method == CHARTED_METHOD,
            Detection.verdict != NOT_ENOUGH_DATA,
            Detection.p_value.is_not(None),
        )
        .order_by(Revision.order_key.desc(), Detection.flagged.desc(), Detection.id)
    )
    if flagged_only:
        query = query.where(Detection.flagged)
    after = after_newest_first(cursor, Revision.order_key, Detection.flagged, Detection.id)
    if after is not None:
        query = query.where(after)
    rows = list(session.execute(query.add_columns(Revision.order_key).limit(limit)))
    following = None
    if limit is not None and len(rows) == limit:
        found, _, _, _, key = rows[-1]
        following = encode_cursor(key, found.flagged, found.id)
    context = component_config(session, component.id).context_counters
    return [
        ChangeOut(
            series=series_ref(series, context),
            revision=title,
            baseline=base,
            method=found.method,
            score=found.score,
            p_value=found.p_value,
            effect=found.effect
            if found.effect is not None and math.isfinite(found.effect)
            else None,
            flagged=found.flagged,
            created=found.created,
        )
        for found, series, title, base, _ in rows
    ], following
