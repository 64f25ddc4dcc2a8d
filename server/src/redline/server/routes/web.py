"""The browser UI: pages rendered on the server (Jinja2), plotly.js served by Redline itself.

Addresses: ``/`` (components, hosts, the job queue); ``/components/{name}`` (trend charts by case
and phase, filters kept in the address; ``/components/{name}/trends``, their data as JSON, for
loading earlier history on zoom and pan); ``/components/{name}/revisions/{title}`` (jobs and
verdicts); ``/components/{name}/compare?base=&candidate=``; ``/components/{name}/executions``
(paged, filtered by revision, host and state); ``/detections/{id}`` (why a change was flagged);
``/executions/{id}`` (raw counters, counters against parameters, the recording). Elsewhere:
``/regressions...`` (`regression_pages`), ``/signin`` and ``/signout`` (`signin_pages`),
``/settings/...`` (`settings_pages`). Each page reads through the same
services as the API; a page for something that does not exist is a 404 page naming it, a bad
filter a 400 page naming it.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from urllib.parse import urlencode

import plotly
from fastapi import FastAPI, Request, Response
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from redline.server.api.deps import SessionDep
from redline.server.core.config import Settings
from redline.server.models import JobState
from redline.server.routes import regression_pages, settings_pages, signin_pages
from redline.server.services import (
    compare,
    components,
    dashboard,
    detection_config,
    execution_view,
    executions,
    home,
    learning,
    open_regressions,
    regressions,
    revision_view,
    revisions,
    trend_view,
    why,
)
from redline.server.services.errors import BadRequest, NotFound
from redline.server.services.gate import gate
from redline.server.services.revision_summaries import WAITING
from redline.server.ui.compare_figures import comparison_figure
from redline.server.ui.detail_figures import execution_figures, why_figures
from redline.server.ui.figures import trend_charts
from redline.server.ui.model_figures import model_figures
from redline.server.ui.pages import page, page_router, problem

PLOTLY_JS = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
router = page_router()
#: revisions and regressions listed on a component's page (the rest are a link away)
LISTED = 20


@router.get("/", response_class=HTMLResponse)
def index(request: Request, session: SessionDep) -> HTMLResponse:
    return page(
        request,
        "index.html",
        {
            "components": home.overview(session),
            "hosts": home.list_hosts(session),
            "queue": home.queue(session),
        },
    )


def _unjudged(verdicts: dict[str, str]) -> str:
    """Why the trends may show no change marks: how many of the newest revisions are "not
    enough data" yet, and the commonest reason ("" when none is). ("have no verdict yet" read
    as a contradiction to a trial, beside the revision's row saying "not enough data".)"""
    waiting = [said for said in verdicts.values() if WAITING in said]
    if not waiting:
        return ""
    reason = Counter(waiting).most_common(1)[0][0]
    return (
        f"{len(waiting)} of the newest {len(verdicts)} revisions are not judged yet (not enough "
        f"data: no change can be marked). The commonest reason, {reason}"
    )


@router.get("/components/{name}", response_class=HTMLResponse)
def component_page(name: str, request: Request, session: SessionDep) -> HTMLResponse:
    try:
        component = components.get_component(session, name)
        view = trend_view.TrendView.from_query(request.query_params)
        trends = dashboard.cached_page(session, component, view, trend_charts)
    except (NotFound, BadRequest) as exc:
        return problem(request, exc)
    newest, verdicts = revisions.newest_with_verdicts(session, name, LISTED)
    return page(
        request,
        "component.html",
        {
            "verdicts": verdicts,
            "unjudged": _unjudged(verdicts),
            "component": component,
            "view": view,
            "page": trends,
            "most_revisions": trend_view.MAX_REVISIONS,
            "choices": dashboard.choices(session, component),
            "revisions": newest,
            # standing, as the regressions page lists them unless asked for all: a sixth trial's
            # page listed three "not confirmed" ones of unchanged commits beside the real one
            "regressions": regressions.list_regressions(
                session, name, confirmation="standing", limit=LISTED
            )[0],
            "open_in": open_regressions.open_in(
                [r.title for r in newest],
                regressions.list_regressions(session, name, regressions.OPEN, limit=LISTED)[0],
            ),
            "models": learning.list_models(session, name)[:LISTED],
            "runtime_alerts": learning.list_alerts(session, name, LISTED),
            "executions": executions.newest_executions(session, component, LISTED),
        },
    )


#: executions on a page of the executions list (the API's page size, with its cursor)
EXECUTIONS_PAGE = 100


@router.get("/components/{name}/executions", response_class=HTMLResponse)
def executions_page(
    name: str,
    request: Request,
    session: SessionDep,
    revision: str = "",
    host: str = "",
    state: str = "",
    cursor: str = "",
) -> HTMLResponse:
    """The component's executions, newest revision first, filtered by revision, host and job
    state, a page at a time (the API's list and cursor)."""
    filters = {"revision": revision, "host": host, "state": state}
    try:
        component = components.get_component(session, name)
        found, following = executions.list_executions(
            session, name, revision or None, host or None, state or None, EXECUTIONS_PAGE, cursor
        )
    except (NotFound, BadRequest) as exc:
        return problem(request, exc)
    return page(
        request,
        "executions.html",
        {
            "component": component,
            "executions": found,
            "filters": filters,
            "hosts": executions.host_names(session),
            "states": list(JobState.__members__),
            "cursor": cursor,
            "following": following,
            "query": lambda **changes: urlencode(
                {k: v for k, v in {**filters, **changes}.items() if v}
            ),
        },
    )


@router.get("/components/{name}/trends")
def component_trends(name: str, request: Request, session: SessionDep) -> Response:
    """The component page's chart data for a view (the same query as the page), as JSON: what
    the page fetches to load earlier history when a chart is zoomed or panned past its oldest
    revision. ``{"earlier": the oldest revision shown when there are older ones, "view": the
    page's query for this view, "page": {"charts", "revisions"}}``; a bad filter is a 400."""
    component = components.get_component(session, name)
    view = trend_view.TrendView.from_query(request.query_params)
    trends = dashboard.cached_page(session, component, view, trend_charts)
    head = json.dumps({"earlier": trends.earlier, "view": view.query()})
    return Response(f'{head[:-1]},"page":{trends.data}}}', media_type="application/json")


@router.get("/components/{name}/models/{model_id}", response_class=HTMLResponse)
def model_page(name: str, model_id: int, request: Request, session: SessionDep) -> HTMLResponse:
    try:
        row = learning.get_model(session, name, model_id)
    except NotFound as exc:
        return problem(request, exc)
    return page(
        request,
        "model.html",
        {
            "component": name,
            "model": learning.model_out(row, name),
            "figures": model_figures(row.plot or {}),
        },
    )


@router.get("/components/{name}/revisions/{title}", response_class=HTMLResponse)
def revision_page(name: str, title: str, request: Request, session: SessionDep) -> HTMLResponse:
    try:
        revision = revisions.revision_detail(session, name, title)
    except NotFound as exc:
        return problem(request, exc)
    return page(
        request,
        "revision.html",
        {
            "revision": revision,
            "gate": gate(session, name, title),
            "notes": revisions.execution_notes(session, revision.id),
            "detections": regressions.list_detections(session, name, revision=title)[0],
            # which methods' changes fail CI (a trial read a KS mark beside execution_shift's
            # "no change" for one series, with nothing saying which decides)
            "alarming": detection_config.component_config(
                session, components.get_component(session, name).id
            ).alarming,
            "values": revision_view.verdict_values(session, revision.id),
            "facts": revision_view.execution_facts(session, revision.id),
        },
    )


#: revisions offered in the compare page's choices (the newest)
COMPARE_CHOICES = 500


@router.get("/components/{name}/compare", response_class=HTMLResponse, response_model=None)
def compare_page(
    name: str,
    request: Request,
    session: SessionDep,
    base: str = "",
    candidate: str = "",
    base_through: str | None = None,
    candidate_through: str | None = None,
) -> HTMLResponse | RedirectResponse:
    """Any two revisions or ranges (``a..b``, pooled), chosen in the page: each series' change,
    KS's D, the candidate's stored verdicts, and a chart. The form's "through" choices make a
    range: the page answers with the address that says it (``?base=a..b``)."""
    if base_through is not None or candidate_through is not None:
        sides = {
            "base": f"{base}..{base_through}" if base_through and base_through != base else base,
            "candidate": f"{candidate}..{candidate_through}"
            if candidate_through and candidate_through != candidate
            else candidate,
        }
        return RedirectResponse(f"?{urlencode(sides)}", status_code=303)
    try:
        component = components.get_component(session, name)
        choices = revisions.newest_revisions(session, name, COMPARE_CHOICES)
        for side, spec in (("base", base), ("candidate", candidate)):
            if spec:  # one side given alone is checked too (a trial's ?base=zzz answered 200)
                compare.revision_range(session, component, spec, side)
        found = compare.compare(session, name, base, candidate) if base and candidate else None
        verdicts = compare.candidate_verdicts(session, name, candidate) if found else {}
    except (NotFound, BadRequest) as exc:
        return problem(request, exc)
    comparison = found if found is not None and found.series else None
    base = base or (choices[1].title if len(choices) > 1 else "")
    candidate = candidate or (choices[0].title if choices else "")
    return page(
        request,
        "compare.html",
        {
            "component": component,
            "revisions": choices,
            "base": found.base_revisions if found else [base],
            "candidate": found.candidate_revisions if found else [candidate],
            "comparison": comparison,
            "compared": found is not None,
            "verdicts": verdicts,
            "methods": sorted({method for by in verdicts.values() for method in by}),
            "figures": [comparison_figure(comparison)] if comparison else [],
        },
    )


@router.get("/detections/{detection_id}", response_class=HTMLResponse)
def why_page(detection_id: int, request: Request, session: SessionDep) -> HTMLResponse:
    """Why a change was flagged: what the detection compared, its thresholds and floors, and
    the confirmation pairs."""
    try:
        found = why.why_flagged(session, detection_id)
    except NotFound as exc:
        return problem(request, exc)
    return page(request, "why.html", {"why": found, "figures": why_figures(found)})


@router.get("/executions/{execution_id}", response_class=HTMLResponse)
def execution_page(execution_id: int, request: Request, session: SessionDep) -> HTMLResponse:
    try:
        view = execution_view.execution_view(session, execution_id)
    except NotFound as exc:
        return problem(request, exc)
    return page(request, "execution.html", {"view": view, "figures": execution_figures(view)})


@router.get("/executions/{execution_id}/recording", response_model=None)
def execution_recording(
    execution_id: int, request: Request, session: SessionDep
) -> FileResponse | HTMLResponse:
    """The execution's MCAP recording, as the agent uploaded it (while retention keeps it)."""
    try:
        path, why_none = execution_view.recording_file(session, execution_id)
    except NotFound as exc:
        return problem(request, exc)
    if path is None:
        return problem(request, NotFound(f"execution {execution_id}: {why_none}"))
    return FileResponse(
        path, media_type="application/octet-stream", filename=f"execution-{execution_id}.mcap"
    )


@router.get("/static/plotly.min.js")
def plotly_js() -> FileResponse:
    """plotly.js from the plotly package itself: the UI never loads code from a CDN."""
    return FileResponse(PLOTLY_JS, media_type="text/javascript")


#: a change's confirmation as the pages say it: as its regression's is said ("held" and "dropped"
#: are the API's words; a trial read "held" on one page and "confirmed" on the next)
CONFIRMATION_WORDS = {"held": "confirmed", "dropped": "not confirmed"}


def confirmation_word(state: str) -> str:
    return CONFIRMATION_WORDS.get(state, state)


def mount(app: FastAPI, settings: Settings) -> None:
    """Add the UI's routes, templates (``web/templates``) and static files (``web/static``)."""
    app.state.templates = Jinja2Templates(directory=settings.web_dir / "templates")
    app.state.templates.env.filters["confirmation"] = confirmation_word
    app.include_router(router)
    app.include_router(regression_pages.router)
    app.include_router(signin_pages.router)
    app.include_router(settings_pages.router)
    app.mount("/static", StaticFiles(directory=settings.web_dir / "static"), name="static")
