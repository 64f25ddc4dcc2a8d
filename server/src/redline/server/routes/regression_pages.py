"""The regressions' pages: ``/regressions`` (every component's, filtered by component, triage
state, confirmation and method, a page at a time with the API's cursor), ``/regressions/{id}``
and its triage form (``/regressions/{id}/triage``, signed in with ``triage``)."""

from __future__ import annotations

from urllib.parse import urlencode

from fastapi import Request, Response
from fastapi.responses import HTMLResponse, RedirectResponse
from pydantic import ValidationError
from redline.detect.registry import DETECTORS, TITLES
from redline.server.api.deps import SessionDep
from redline.server.models import RegressionState
from redline.server.schemas.regressions import TriageRequest
from redline.server.services import components, regressions, signin
from redline.server.services.errors import BadRequest, Forbidden, NotFound
from redline.server.ui.pages import (
    form_errors,
    form_fields,
    page,
    page_router,
    problem,
    signed_in,
)

router = page_router()
CONFIRMATIONS = ("suspected", "confirmed", "not_confirmed", "withdrawn")
#: the list's default: the regressions that stand (confirmed or suspected); "all" shows every
#: one, those the re-runs or later revisions dropped too (a new user found a dropped, noisy
#: rss_bytes "regression" listed beside the real one)
STANDING, ALL = "standing", "all"
#: regressions on a page of the list (the next ones are a link away, by the API's cursor)
PAGE = 100


def _checked(state: str, confirmation: str, method: str) -> None:
    """A `BadRequest` naming a filter whose value is none of those it takes."""
    for name, value, allowed in (
        ("state", state, [regressions.OPEN, *RegressionState.__members__]),
        ("confirmation", confirmation, (STANDING, ALL, *CONFIRMATIONS)),
        ("method", method, list(DETECTORS)),
    ):
        if value and value not in allowed:
            raise BadRequest(f"{name}: one of {', '.join(allowed)}, not {value!r}")


@router.get("/regressions", response_class=HTMLResponse)
def regressions_page(
    request: Request,
    session: SessionDep,
    component: str = "",
    state: str = "",
    confirmation: str = STANDING,
    method: str = "",
    cursor: str = "",
) -> HTMLResponse:
    filters = {
        "component": component,
        "state": state,
        "confirmation": confirmation,
        "method": method,
    }
    try:
        _checked(state, confirmation, method)
        found, following = regressions.list_regressions(
            session,
            component or None,
            state or None,
            ALL if confirmation in ("", ALL) else confirmation,
            limit=PAGE,
            cursor=cursor or None,
            method=method or None,
        )
    except (NotFound, BadRequest) as exc:
        return problem(request, exc)
    chosen = {name: value for name, value in filters.items() if value}
    return page(
        request,
        "regressions.html",
        {
            "regressions": found,
            "filters": filters,
            "components": [c.name for c in components.list_components(session)],
            "states": [regressions.OPEN, *RegressionState.__members__],
            "confirmations": CONFIRMATIONS,
            "methods": list(DETECTORS),
            "titles": TITLES,
            "first": urlencode(chosen) if cursor else None,
            "following": urlencode({**chosen, "cursor": following}) if following else None,
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


@router.post("/regressions/{regression_id}/triage", response_class=HTMLResponse)
async def triage_form(regression_id: int, request: Request, session: SessionDep) -> Response:
    """The regression page's triage form: a signed-in session with ``triage`` (or ``admin``), and
    the session's form token; the page again, with the outcome."""
    form = await form_fields(request)
    back = (f"/regressions/{regression_id}", f"regression #{regression_id}")
    try:
        row = signed_in(request)
        who = signin.authorize(row, form.get("csrf", ""), "triage")
        name = regressions.component_of(session, regression_id)
        signin.ensure_component(row, name)  # `authorize` found the session
        if not form.get("state"):  # the form sent without a state chosen (a trial met pydantic)
            raise BadRequest(
                "triage: choose the state to set: acknowledge, confirm, ignore, fixed or false "
                "positive (a comment alone is not kept)"
            )
        change = TriageRequest(state=form["state"], comment=form.get("comment", ""))
        regressions.triage(session, name, regression_id, change, who)
    except (NotFound, BadRequest, Forbidden) as exc:
        return problem(request, exc, back)
    except ValidationError as exc:  # a state that is none, a comment too long
        return problem(request, BadRequest(f"triage: {form_errors(exc)}"), back)
    return RedirectResponse(f"/regressions/{regression_id}", status_code=303)
