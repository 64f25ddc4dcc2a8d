"""The component page's trend view: which series, which revisions, their points and their marks.

A view is what the page's address says (`redline.server.services.trend_view`): filters, how
many of the newest revisions (100 by default), where the history ends (``before``). Only
those revisions are read, so a page costs the same at 100 and at 10,000 revisions, and only the
revisions' own executions: confirmation runs are not part of a trend.

The figures of a view are cached in ``figure_cache`` under the view's data version (its
revisions, their newest execution and analysis, the component's newest regression update: read
from the view's revisions alone, see `data_version`), rendered by the worker after each analysis
for the default view (`warm`), and by the page on a miss.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from redline.detect.confirmation import DROPPED, HELD, SUSPECTED
from redline.detect.summary import Pooled
from redline.server.models import (
    Component,
    Detection,
    Execution,
    FigureCache,
    Host,
    Job,
    Regression,
    Revision,
    Series,
    Summary,
    revision_place,
    utcnow,
)
from redline.server.schemas.results import SeriesRef
from redline.server.services.errors import BadRequest
from redline.server.services.executions import host_names
from redline.server.services.read import FIELDS
from redline.server.services.results import series_ref
from redline.server.services.trend_view import (
    Identity,
    TrendView,
    check_filters,
    choices_of,
    cut_charts,
)
from sqlalchemy import ColumnElement, delete, exists, func, or_, select, true
from sqlalchemy.dialects.postgresql import insert
from sqlalchemy.orm import Session


@dataclass(frozen=True)
class TrendRevision:
    id: int
    title: str
    commit: str
    when: datetime | None


#: a flagged change's own confirmation (`Detection.confirmation`) as its mark's
MARKED = {HELD: "confirmed", DROPPED: "not_confirmed", SUSPECTED: "suspected"}


@dataclass(frozen=True)
class Mark:
    """A flagged change, drawn on the revision it was flagged at: in a regression (its
    confirmation then: suspected, confirmed, not_confirmed), or flagged by a method that does not
    alarm (``regression_id`` None, confirmation ``flagged``)."""

    regression_id: int | None
    confirmation: str
    method: str
    effect: float | None


@dataclass
class TrendSeries:
    ref: SeriesRef
    points: dict[int, Pooled] = field(default_factory=dict)  # by revision id
    marks: dict[int, Mark] = field(default_factory=dict)


@dataclass
class TrendData:
    revisions: list[TrendRevision]  # oldest first
    series: list[TrendSeries]
    earlier: str | None  # the oldest revision shown, when there are older ones
    note: str = ""  # what the page says of the charts it does not draw (`cut_charts`)


@dataclass(frozen=True)
class Window:
    """The revisions a view shows, newest first, and one more when older ones exist: its own
    executions' revisions (on the view's host), up to ``before``. Read by every request (for
    the data version), in as many index steps as the view has revisions."""

    revisions: list[Revision]
    ran: list[ColumnElement[bool]]  # which executions count: the revisions' own, the host's


def window(session: Session, component: Component, view: TrendView) -> Window:
    ran = [Job.pair == 0] + ([Job.host_id == _host_id(session, view.host)] if view.host else [])
    own = exists().where(Execution.revision_id == Revision.id, Job.id == Execution.job_id, *ran)
    query = select(Revision).where(Revision.component_id == component.id, own)
    if view.before:
        end = session.execute(
            select(Revision.order_key, Revision.id).where(
                Revision.component_id == component.id, Revision.title == view.before
            )
        ).first()
        if end is None:
            raise BadRequest(f"before: {component.name} has no revision {view.before!r}")
        query = query.where(revision_place() < tuple(end))
    query = query.order_by(Revision.order_key.desc(), Revision.id.desc()).limit(view.revisions + 1)
    return Window(list(session.scalars(query)), ran)


def trend_data(
    session: Session, component: Component, view: TrendView, shown_in: Window | None = None
) -> TrendData:
    """The series the view selects, with a point per revision among the newest it shows."""
    every = _identities(session, component.id)
    selected = {sid: identity for sid, identity in every.items() if view.selects(identity)}
    if every and not selected:
        check_filters(component, view, list(every.values()))
    drawn, note = cut_charts(selected)
    chosen = {
        series.id: TrendSeries(series_ref(series))
        for series in session.scalars(select(Series).where(Series.id.in_(drawn)))
    }
    found = shown_in or window(session, component, view)
    newest, ran = found.revisions, found.ran
    earlier = newest[view.revisions - 1].title if len(newest) > view.revisions else None
    shown = newest[: view.revisions][::-1]
    ids = [revision.id for revision in shown]
    if ids and chosen:
        rows = session.execute(
            select(Summary.series_id, Execution.revision_id, Summary.n, Summary.mean, Summary.std)
            .join(Execution, Execution.id == Summary.execution_id)
            .join(Job, Job.id == Execution.job_id)
            .where(Execution.revision_id.in_(ids), Summary.series_id.in_(list(chosen)), *ran)
        )
        for series_id, revision_id, n, mean, std in rows:
            chosen[series_id].points.setdefault(revision_id, Pooled()).add(n, mean, std)
        marks = session.execute(
            select(
                Detection.series_id,
                Detection.revision_id,
                Regression.id,
                Regression.confirmation,
                Detection.confirmation,
                Detection.method,
                Detection.effect,
            )
            .outerjoin(Regression, Regression.id == Detection.regression_id)
            .where(
                Detection.flagged,
                Detection.revision_id.in_(ids),
                Detection.series_id.in_(list(chosen)),
                # a flag in no regression and never confirmed, only when asked (`TrendView.flags`)
                true()
                if view.flags
                else or_(Detection.regression_id.is_not(None), Detection.confirmation.in_(MARKED)),
            )
            .order_by(Detection.regression_id.is_(None), Detection.id)  # regressions first
        )
        for series_id, revision_id, regression_id, grouped, own, method, effect in marks:
            # the change's own confirmation before its regression's: a flag the re-runs dropped
            # is not drawn confirmed for a later change grouped with it
            confirmation = MARKED.get(own) or grouped or "flagged"
            chosen[series_id].marks.setdefault(
                revision_id, Mark(regression_id, confirmation, method, effect)
            )
    return TrendData(
        revisions=[
            TrendRevision(r.id, r.title, r.commit, r.committed_at or r.created) for r in shown
        ],
        series=[s for s in chosen.values() if s.points],
        earlier=earlier,
        note=note,
    )


def _identities(session: Session, component_id: int) -> dict[int, Identity]:
    """Each series of the component (by id) as a view selects it."""
    rows = session.execute(
        select(
            Series.id, Series.case, Series.phase, Series.process, Series.counter, Series.params
        ).where(Series.component_id == component_id)
    )
    parsed: dict[str, dict[str, Any]] = {}  # a few parameter sets, shared by many series
    return {
        series_id: Identity(case, phase, process, counter, _parsed(parsed, params))
        for series_id, case, phase, process, counter, params in rows
    }


def _parsed(seen: dict[str, dict[str, Any]], text: str) -> dict[str, Any]:
    if text not in seen:
        seen[text] = json.loads(text)
    return seen[text]


def _host_id(session: Session, name: str) -> int:
    """The id of the performance host named ``name``; a `BadRequest` naming it otherwise."""
    found = session.scalar(select(Host.id).where(Host.name == name))
    if found is None:
        raise BadRequest(f"host: no performance host {name!r}")
    return found


#: how the pages draw what they show, in a cached page's version: raised when an upgrade draws it
#: otherwise, so that no page cached before shows the old drawing (2: flags that do not alarm
#: only when asked)
DRAWING = 2


def data_version(session: Session, component_id: int, shown: Window) -> str:
    """Changes whenever what a view's page shows may have: which revisions it shows (their
    titles and commits), one of them analysed (after every ingest and re-analysis: its time
    set, or cleared by a new ingest), an execution of theirs stored, a regression of the
    component updated (its confirmation). Read from the view's revisions alone and the
    component's regressions (a few per flagged change), not from the whole history: it costs
    the same at 100 and at 10,000 revisions."""
    seen = "\x00".join(
        f"{r.id}|{r.title}|{r.commit}|{r.committed_at}|{r.analyzed_at}" for r in shown.revisions
    )
    ids = [revision.id for revision in shown.revisions]
    # each of their executions by its revision (an index step each), not max() over the table:
    # the planner walked the executions newest first for that, past every later revision's
    executions = session.scalars(select(Execution.id).where(Execution.revision_id.in_(ids)))
    stored = max(executions, default=None)
    updated = session.scalar(
        select(func.max(Regression.updated)).where(Regression.component_id == component_id)
    )
    return f"{hashlib.sha256(seen.encode()).hexdigest()[:32]}|{stored}|{updated}|{DRAWING}"


#: renders a view's charts: `redline.server.ui.figures.trend_charts`
Render = Callable[[TrendData, TrendView], list[dict[str, Any]]]
#: what may not appear as such in JSON inside an HTML <script> element
SCRIPT_SAFE = str.maketrans({"<": "\\u003c", ">": "\\u003e", "&": "\\u0026", "'": "\\u0027"})


@dataclass(frozen=True)
class TrendPage:
    """A view's charts as JSON text safe inside ``<script>`` (``{"charts", "revisions"}``: each
    revision's title, commit and time, shown on hover), where the earlier history starts, and
    what the page says of the charts it left out."""

    data: str
    earlier: str | None
    note: str = ""


def render_page(data: TrendData, view: TrendView, render: Render) -> TrendPage:
    content = {
        "charts": render(data, view),
        "revisions": [
            [r.title, r.commit[:12], r.when.strftime("%Y-%m-%d %H:%M") if r.when else ""]
            for r in data.revisions
        ],
    }
    text = json.dumps(content, separators=(",", ":"), allow_nan=False).translate(SCRIPT_SAFE)
    return TrendPage(text, data.earlier, data.note)


def cached_page(
    session: Session, component: Component, view: TrendView, render: Render
) -> TrendPage:
    """The view's page from the cache when it is current, else rendered now and stored."""
    shown = window(session, component, view)
    key, version = view.query(), data_version(session, component.id, shown)
    row = session.scalar(
        select(FigureCache).where(FigureCache.component_id == component.id, FigureCache.view == key)
    )
    if row is not None and row.version == version:
        return TrendPage(row.figures, row.earlier, row.note)
    rendered = render_page(trend_data(session, component, view, shown), view, render)
    store(session, component.id, key, version, rendered)
    session.commit()
    return rendered


def warm(session: Session, component_id: int, render: Render) -> None:
    """Render the default view of the component into the cache (the worker, after analysis)."""
    component = session.get(Component, component_id)
    if component is not None:
        cached_page(session, component, TrendView(), render)


def choices(session: Session, component: Component) -> dict[str, list[str]]:
    """The values each filter can take: every case, phase, process, counter, parameter, and
    every performance host (a handful: which ran this component would cost a look at its whole
    history)."""
    of = Series.component_id == component.id
    values = {
        name: session.scalars(select(getattr(Series, name)).where(of).distinct()) for name in FIELDS
    }
    param_sets = [
        json.loads(text) for text in session.scalars(select(Series.params).where(of).distinct())
    ]
    return {**choices_of(values, param_sets), "host": host_names(session)}


#: views kept per component (each address is a view: the least recently rendered go first)
MAX_CACHED_VIEWS = 50


def store(session: Session, component_id: int, key: str, version: str, rendered: TrendPage) -> None:
    """Keep a view's page; two requests rendering the same view at once both succeed."""
    values = {
        "component_id": component_id,
        "view": key,
        "version": version,
        "figures": rendered.data,
        "earlier": rendered.earlier,
        "note": rendered.note,
        "created": utcnow(),
    }
    statement = insert(FigureCache).values(**values)
    session.execute(
        statement.on_conflict_do_update(
            index_elements=[FigureCache.component_id, FigureCache.view],
            set_={
                name: statement.excluded[name]
                for name in ("version", "figures", "earlier", "note", "created")
            },
        )
    )
    kept = (
        select(FigureCache.id)
        .where(FigureCache.component_id == component_id)
        .order_by(FigureCache.created.desc())
        .limit(MAX_CACHED_VIEWS)
    )
    session.execute(
        delete(FigureCache).where(
            FigureCache.component_id == component_id, FigureCache.id.not_in(kept.scalar_subquery())
        )
    )
