"""The browser UI: a component index and one trend page per component. plotly.js is served here."""

from __future__ import annotations

from pathlib import Path

import plotly
from fastapi import APIRouter, FastAPI, Request
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from redline.server.api.deps import READ, SessionDep
from redline.server.core.bodies import JsonRoute
from redline.server.core.config import Settings
from redline.server.services import components, regressions, results, revisions
from redline.server.services.errors import NotFound
from redline.server.ui.figures import trend_figure

PLOTLY_JS = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"

# REDLINE_READ_ACCESS=token: the pages need a read token (cookie redline_token or ?token=)
router = APIRouter(include_in_schema=False, dependencies=READ, route_class=JsonRoute)


def _templates(request: Request) -> Jinja2Templates:
    return request.app.state.templates


@router.get("/", response_class=HTMLResponse)
def index(request: Request, session: SessionDep) -> HTMLResponse:
    return _templates(request).TemplateResponse(
        request, "index.html", {"components": components.list_components(session)}
    )


@router.get("/components/{name}", response_class=HTMLResponse)
def component_page(name: str, request: Request, session: SessionDep) -> HTMLResponse:
    try:
        component = components.get_component(session, name)
    except NotFound as exc:
        return _templates(request).TemplateResponse(
            request, "not_found.html", {"message": exc.detail}, status_code=404
        )
    changes = results.component_changes(session, name)
    figures = [trend_figure(series, changes) for series in results.component_series(session, name)]
    return _templates(request).TemplateResponse(
        request,
        "component.html",
        {
            "component": component,
            "figures": figures,
            "revisions": revisions.list_revisions(session, name),
            "flagged": [change for change in changes if change.flagged],
            "regressions": regressions.list_regressions(session, name),
            "verdicts": revisions.revision_verdicts(session, name),
        },
    )


@router.get("/static/plotly.min.js")
def plotly_js() -> FileResponse:
    """plotly.js from the plotly package itself: the UI never loads code from a CDN."""
    return FileResponse(PLOTLY_JS, media_type="text/javascript")


def mount(app: FastAPI, settings: Settings) -> None:
    """Add the UI's routes, templates (``web/templates``) and static files (``web/static``)."""
    app.state.templates = Jinja2Templates(directory=settings.web_dir / "templates")
    app.include_router(router)
    app.mount("/static", StaticFiles(directory=settings.web_dir / "static"), name="static")
