"""The browser UI: pages rendered on the server (Jinja2), plotly.js served by Redline itself.

Addresses: ``/`` (components, hosts, the job queue); ``/components/{name}`` (trend charts by case
and phase, filters kept in the address; ``/components/{name}/trends``, their data as JSON, for
loading earlier history on zoom and pan); ``/components/{name}/revisions/{title}`` (jobs and
verdicts); ``/components/{name}/compare?base=&candidate=``; ``/regressions`` and
``/regressions/{id}`` (triage when signed in); ``/detections/{id}`` (why a change was flagged);
``/executions/{id}`` (raw counters, counters against parameters, the recording); ``/signin``;
``/settings/...`` (`redline.server.routes.settings_pages`). Each page reads through the same
services as the API; a page for something that does not exist is a 404 page naming it, a bad
filter a 400 page naming it.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import plotly
from fastapi import FastAPI, Request, Response
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from pydantic import ValidationError
from redline.server.api.deps import SessionDep
from redline.server.core.config import Settings
from redline.server.models import RegressionState
from redline.server.routes import settings_pages
from redline.server.schemas.regressions import TriageRequest
from redline.server.services import (
    compare,
    components,
    dashboard,
    execution_view,
    home,
    learning,
    regressions,
    revisions,
    signin,
    why,
)
from redline.server.services.errors import BadRequest, Forbidden, NotFound
from redline.server.services.revisions import WAITING
from redline.server.ui.compare_figures import comparison_figure
from redline.server.ui.detail_figures import execution_figures, why_figures
from redline.server.ui.figures import trend_charts
from redline.server.ui.model_figures import model_figures
from redline.server.ui.pages import (
    form_errors,
    form_fields,
    page,
    page_router,
    problem,
    signed_in,
)

PLOTLY_JS = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
router = page_router()
auth_router = page_router(read=False)
#: revisions and regressions listed on a component's page (the rest are a link away)
LISTED = 20
CONFIRMATIONS = ("suspected", "confirmed", "not_confirmed")


def _local(target: str) -> str:
    """Where to go after signing in: a path on this server only, never another host."""
    return target if target.startswith("/") and not target.startswith("//") else "/"


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
    """Why the trends may show no change marks: how many of the newest revisions have no
    verdict yet, and the commonest reason ("" when every one has one)."""
    waiting = [said for said in verdicts.values() if WAITING in said]
    if not waiting:
        return ""
    reason = Counter(waiting).most_common(1)[0][0]
    return f"{len(waiting)} of the newest {len(verdicts)} revisions have no verdict yet ({reason})"


@router.get("/components/{name}", response_class=HTMLResponse)
def component_page(name: str, request: Request, session: SessionDep) -> HTMLResponse:
    try:
        component = components.get_component(session, name)
        view = dashboard.TrendView.from_query(request.query_params)
        trends = dashboard.cached_page(session, component, view, trend_charts)
    except (NotFound, BadRequest) as exc:
        return problem(request, exc)
    newest = revisions.newest_revisions(session, name, LISTED)
    verdicts = revisions.revision_verdicts(session, name, [r.title for r in newest])
    return page(
        request,
        "component.html",
        {
            "verdicts": verdicts,
            "unjudged": _unjudged(verdicts),
            "component": component,
            "view": view,
            "page": trends,
            "most_revisions": dashboard.MAX_REVISIONS,
            "choices": dashboard.choices(session, component),
            "revisions": newest,
            "regressions": regressions.list_regressions(session, name, limit=LISTED)[0],
            "models": learning.list_models(session, name)[:LISTED],
            "runtime_alerts": learning.list_alerts(session, name, LISTED),
        },
    )


@router.get("/components/{name}/trends")
def component_trends(name: str, request: Request, session: SessionDep) -> Response:
    """The component page's chart data for a view (the same query as the page), as JSON: what
    the page fetches to load earlier history when a chart is zoomed or panned past its oldest
    revision. ``{"earlier": the oldest revision shown when there are older ones, "view": the
    page's query for this view, "page": {"charts", "revisions"}}``; a bad filter is a 400."""
    component = components.get_component(session, name)
    view = dashboard.TrendView.from_query(request.query_params)
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
            "notes": revisions.execution_notes(session, revision.id),
            "detections": regressions.list_detections(session, name, revision=title)[0],
        },
    )


#: revisions offered in the compare page's choices (the newest)
COMPARE_CHOICES = 500


@router.get("/components/{name}/compare", response_class=HTMLResponse)
def compare_page(
    name: str, request: Request, session: SessionDep, base: str = "", candidate: str = ""
) -> HTMLResponse:
    """Any two revisions, chosen in the page: each series' change, KS's D, and a chart."""
    try:
        component = components.get_component(session, name)
        choices = revisions.newest_revisions(session, name, COMPARE_CHOICES)
        found = compare.compare(session, name, base, candidate) if base and candidate else None
    except (NotFound, BadRequest) as exc:
        return problem(request, exc)
    comparison = found if found is not None and found.series else None
    return page(
        request,
        "compare.html",
        {
            "component": component,
            "revisions": choices,
            "base": base or (choices[1].title if len(choices) > 1 else ""),
            "candidate": candidate or (choices[0].title if choices else ""),
            "comparison": comparison,
            "figures": [comparison_figure(comparison)] if comparison else [],
        },
    )


@router.get("/regressions", response_class=HTMLResponse)
def regressions_page(
    request: Request,
    session: SessionDep,
    component: str = "",
    state: str = "",
    confirmation: str = "",
) -> HTMLResponse:
    try:
        if state and state not in RegressionState.__members__:
            raise BadRequest(f"state: one of {', '.join(RegressionState.__members__)}")
        if confirmation and confirmation not in CONFIRMATIONS:
            raise BadRequest(f"confirmation: one of {', '.join(CONFIRMATIONS)}")
        found, _ = regressions.list_regressions(
            session, component or None, state or None, confirmation or None, limit=500
        )
    except (NotFound, BadRequest) as exc:
        return problem(request, exc)
    return page(
        request,
        "regressions.html",
        {
            "regressions": found,
            "filters": {"component": component, "state": state, "confirmation": confirmation},
            "components": [c.name for c in components.list_components(session)],
            "states": list(RegressionState.__members__),
            "confirmations": CONFIRMATIONS,
        },
    )


@router.get("/regressions/{regression_id}", response_class=HTMLResponse)
def regression_page(regression_id: int, request: Request, session: SessionDep) -> HTMLResponse:
    try:
        name = regressions.component_of(session, regression_id)
        regression = regressions.regression_detail(session, name, regression_id)
    except NotFound as exc:
        return problem(request, exc)
    return page(request, "regression.html", {"regression": regression})


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


@router.post("/regressions/{regression_id}/triage", response_class=HTMLResponse)
async def triage_form(regression_id: int, request: Request, session: SessionDep) -> Response:
    """The regression page's triage form: a signed-in session with ``ci`` (or ``admin``), and
    the session's form token; the page again, with the outcome."""
    form = await form_fields(request)
    try:
        who = signin.authorize(signed_in(request), form.get("csrf", ""), "ci")
        name = regressions.component_of(session, regression_id)
        change = TriageRequest(state=form.get("state", ""), comment=form.get("comment", ""))
        regressions.triage(session, name, regression_id, change, who)
    except (NotFound, BadRequest, Forbidden) as exc:
        return problem(request, exc)
    except ValidationError as exc:  # a state that is none, a comment too long
        return problem(request, BadRequest(f"triage: {form_errors(exc)}"))
    return RedirectResponse(f"/regressions/{regression_id}", status_code=303)


@auth_router.get("/signin", response_class=HTMLResponse)
def signinpage(request: Request, next: str = "/") -> HTMLResponse:
    return page(request, "signin.html", {"next": _local(next), "message": ""})


@auth_router.post("/signin", response_class=HTMLResponse)
async def signin_form(request: Request, session: SessionDep) -> Response:
    form = await form_fields(request)
    target = _local(form.get("next", "/"))
    try:
        opened = signin.sign_in(
            session, form.get("name", ""), form.get("password", ""), form.get("token", "")
        )
    except Forbidden as exc:
        context = {"next": target, "message": exc.detail}
        return page(request, "signin.html", context, status_code=403)
    answer = RedirectResponse(target, status_code=303)
    answer.set_cookie(
        signin.SESSION_COOKIE,
        opened.secret,
        max_age=signin.SESSION_DAYS * 86400,
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
    return answer


@auth_router.post("/signout", response_class=HTMLResponse)
async def signout_form(request: Request, session: SessionDep) -> Response:
    form = await form_fields(request)
    row = signed_in(request)
    if row is not None and form.get("csrf") == row.csrf:
        signin.sign_out(session, request.cookies.get(signin.SESSION_COOKIE))
    answer = RedirectResponse("/", status_code=303)
    answer.delete_cookie(signin.SESSION_COOKIE)
    return answer


@router.get("/static/plotly.min.js")
def plotly_js() -> FileResponse:
    """plotly.js from the plotly package itself: the UI never loads code from a CDN."""
    return FileResponse(PLOTLY_JS, media_type="text/javascript")


def mount(app: FastAPI, settings: Settings) -> None:
    """Add the UI's routes, templates (``web/templates``) and static files (``web/static``)."""
    app.state.templates = Jinja2Templates(directory=settings.web_dir / "templates")
    app.include_router(router)
    app.include_router(auth_router)
    app.include_router(settings_pages.router)
    app.mount("/static", StaticFiles(directory=settings.web_dir / "static"), name="static")
