"""What every page shares: the signed-in session, rendering, the 404/400/403 page, forms, and
the routers the pages hang on (reading follows `REDLINE_READ_ACCESS`; signing in needs none)."""

from __future__ import annotations

from typing import Any
from urllib.parse import parse_qs

from fastapi import APIRouter, Depends, Request
from fastapi.responses import HTMLResponse
from fastapi.templating import Jinja2Templates
from pydantic import ValidationError
from redline.server.api.deps import READ, SessionDep
from redline.server.core.bodies import JsonRoute
from redline.server.core.security import grants
from redline.server.models import WebSession
from redline.server.services import signin
from redline.server.services.errors import ServiceError, Unprocessable


def _web_session(request: Request, session: SessionDep) -> None:
    """The signed-in session of the request's cookie, if any, for the pages to show and check."""
    request.state.web_session = signin.current(session, request.cookies.get(signin.SESSION_COOKIE))


SIGNED_IN = [Depends(_web_session)]


def page_router(read: bool = True) -> APIRouter:
    """A router of pages: each knows the signed-in session; with ``read``, under
    REDLINE_READ_ACCESS=token, it needs a read token (cookie redline_token or ?token=) or a
    signed-in session (signing in itself needs neither)."""
    dependencies = [*SIGNED_IN, *READ] if read else SIGNED_IN
    return APIRouter(include_in_schema=False, dependencies=dependencies, route_class=JsonRoute)


def signed_in(request: Request) -> WebSession | None:
    return getattr(request.state, "web_session", None)


def may(who: WebSession | None, scope: str, component: str | None = None) -> bool:
    """Whether the signed-in browser ``who`` may do what ``scope`` allows (on ``component``,
    when one is named: a session opened with a token bound to others may not). A page offers
    only the forms it may use: a trial signed in with a read token was shown the triage form,
    and its save answered 403."""
    if who is None or not grants(list(who.scopes), scope):
        return False
    return component is None or signin.acts_on(who, component)


def page(
    request: Request, template: str, context: dict[str, Any], status_code: int = 200
) -> HTMLResponse:
    templates: Jinja2Templates = request.app.state.templates
    who = signed_in(request)
    context = {"signed_in": who, "may": lambda *asked: may(who, *asked), **context}
    return templates.TemplateResponse(request, template, context, status_code=status_code)


def problem(
    request: Request, exc: ServiceError, back: tuple[str, str] | None = None
) -> HTMLResponse:
    """The error page for a service error, with its status and message; ``back``: the page
    the form came from (its address and name), linked beside the home page."""
    code = exc.status_code
    context = {"message": exc.detail, "code": code, "back": back}
    return page(request, "not_found.html", context, code)


#: fields whose values no answer quotes
SECRET_FIELDS = frozenset({"secret", "webhook_secret", "token", "password"})


def error_words(error: Any) -> str:
    """A validation error's message as a person reads it: our validators' own words, without
    pydantic's "Value error, " before them; an empty text or list said to be empty ("Value
    should have at least 1 item after validation" was said of an empty sort key)."""
    empty = error["type"] in ("string_too_short", "too_short") and error.get("input") in ("", [])
    if empty and error.get("ctx", {}).get("min_length") == 1:
        return "must not be empty"
    return str(error["msg"]).removeprefix("Value error, ")


def form_errors(exc: ValidationError) -> str:
    """Each error of a form's fields as "field: what is wrong (given: ...)", for a person:
    pydantic's own text names the model and ends in a link to its documentation. A secret
    field's value is never quoted."""
    said = []
    for error in exc.errors():
        field = ".".join(str(p) for p in error["loc"])
        message = error_words(error)
        given = error.get("input")
        secret = any(part in SECRET_FIELDS for part in error["loc"])
        if (
            isinstance(given, str)
            and error["type"] not in ("string_too_long", "missing", "string_too_short", "too_short")
            and not secret
        ):
            message += f" (given: {given[:80]!r})"
        said.append(f"{field}: {message}" if field else message)
    return "; ".join(said)


async def form_fields(request: Request) -> dict[str, str]:
    """An urlencoded form's fields (the last value of each); its size is bounded like any body.
    A field holding a NUL (``%00``), which no stored text can, is refused naming it, as the
    API's JSON is (a review's triage comment reached the database, which refused it)."""
    fields = parse_qs((await request.body()).decode(errors="replace"), keep_blank_values=True)
    for name, values in fields.items():
        if any("\x00" in value for value in (name, *values)):
            raise Unprocessable(
                f"the form's field {name.replace(chr(0), '')[:80]!r} holds a NUL "
                "character (%00), which no text holds"
            )
    return {name: values[-1] for name, values in fields.items()}
