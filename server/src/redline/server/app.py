"""The FastAPI application factory."""

from __future__ import annotations

import importlib
import json
import logging
import math
import reprlib
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any
from urllib.parse import urlencode

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse, RedirectResponse, Response
from fastapi.routing import APIRoute
from redline.server.core import metrics
from redline.server.core.bodies import BodyLimit
from redline.server.core.config import Settings, get_settings
from redline.server.core.head import HeadAsGet
from redline.server.core.tasks import TaskSender
from redline.server.routes import (
    agent,
    alerts,
    api_docs,
    components,
    executions,
    health,
    imports,
    jobs,
    learning,
    regressions,
    revisions,
    series,
    tokens,
    web,
    webhooks,
)
from redline.server.schemas.fields import SECRET_LENGTH, escaped
from redline.server.services.errors import (
    BadRequest,
    Forbidden,
    NotFound,
    ServiceError,
    Unprocessable,
)
from redline.server.ui.pages import SECRET_FIELDS, error_words, problem
from sqlalchemy.exc import DataError
from starlette.exceptions import HTTPException as StarletteHTTPException


def _huge_path_id(request: Request) -> bool:
    """Whether the address names an id past any stored one (a job's POST said "integer out of
    range" with a 422, where the same id's GET said 404)."""
    return any(
        (key in ("id", "ident", "name_or_id") or key.endswith("_id"))  # not a name of digits
        and isinstance(value, str)
        and value.lstrip("-").isdigit()
        and abs(int(value)) >= 2**31
        for key, value in request.path_params.items()
    )


async def _unstorable(request: Request, exc: Exception) -> Response:
    """A value Postgres cannot hold (an id past 2**31, a NUL in a text): the caller's fault. A
    read, or an address, naming such an id asks for something that cannot exist: 404, not
    "cannot be stored"."""
    orig = getattr(exc, "orig", None) or exc
    reason = (str(orig).strip().splitlines() or [type(orig).__name__])[0]
    if "out of range" in reason and (request.method in ("GET", "HEAD") or _huge_path_id(request)):
        missing = NotFound(f"there is nothing at {request.url.path[:200]}: an id out of range")
        return await _service_error(request, missing)
    # a trial's GET of .../revisions/%00 was told a value "cannot be stored", naming Postgres
    in_path = [key for key, value in request.path_params.items() if "\x00" in str(value)]
    given = [key for key, value in request.query_params.multi_items() if "\x00" in value]
    if "NUL" in reason and (in_path or given):
        named = escaped((in_path + given)[0])[:80]
        said = f"{named} holds a NUL character (%00), which no name or value holds"
        refused: ServiceError = (  # an address holding one names nothing, whatever the method
            NotFound(f"there is nothing at {escaped(request.url.path)[:200]}: {said}")
            if in_path
            else Unprocessable(said)
        )
        return await _service_error(request, refused)
    return await _service_error(
        request, Unprocessable(f"a value in the request cannot be stored: {reason}")
    )


async def _no_route(request: Request, exc: Exception) -> Response:
    """Starlette's own refusals (no such address, a method it does not take): the error page
    for a browser, JSON otherwise."""
    assert isinstance(exc, StarletteHTTPException)
    if _for_a_browser(request) and exc.status_code == 401:
        return RedirectResponse(_signin_address(request), status_code=303)
    if _a_page(request) and exc.status_code in (404, 405):
        return problem(request, NotFound(f"there is no page at {request.url.path[:200]}"))
    if _for_a_browser(request) and _a_page(request) and exc.status_code == 403:
        return problem(request, Forbidden(str(exc.detail)), (_signin_address(request), "sign in"))
    return JSONResponse({"detail": exc.detail}, status_code=exc.status_code, headers=exc.headers)


def _signin_address(request: Request) -> str:
    """The sign-in page, to come back to this page (less a refused ``?token=``) after it."""
    query = urlencode([(k, v) for k, v in request.query_params.multi_items() if k != "token"])
    back = request.url.path + (f"?{query}" if query else "")
    return "/signin?" + urlencode({"next": back})


_EXCERPT = reprlib.Repr()  # keyword arguments only from Python 3.12
_EXCERPT.maxlevel, _EXCERPT.maxstring, _EXCERPT.maxother = 2, 80, 80
_EXCERPT.maxlist = _EXCERPT.maxdict = 4


def _excerpt(value: Any) -> Any:
    """What a 422 quotes of the input at fault: a number as it is, anything else cut short.
    JSON has no NaN or infinity, so those are quoted as text."""
    if isinstance(value, bool) or value is None:
        return value
    if isinstance(value, int):
        return value if abs(value) < 10**18 else f"{str(value)[:20]}... ({len(str(value))} digits)"
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, dict | list):  # quoted as the JSON it came as, not as Python
        value = json.dumps(_shallow(value, 1), default=str, ensure_ascii=False)
    if isinstance(value, str):
        return _cut(value)
    return _EXCERPT.repr(value)


def _cut(value: str) -> str:
    """``value`` in at most 80 characters, those `one_line` refuses as their escapes (a U+202E
    quoted raw reversed the rest of the line it was read in), never cutting one in two."""
    whole = escaped(value[:81])
    if len(value) <= 80 and len(whole) <= 80:
        return whole
    kept: list[str] = []
    length = 0
    for char in value[:77]:
        piece = escaped(char)
        if length + len(piece) > 77:
            break
        kept.append(piece)
        length += len(piece)
    return "".join(kept) + "..."


def _shallow(value: Any, depth: int) -> Any:
    """``value`` with at most 4 items a level and ``depth`` levels: what an excerpt can show."""
    if isinstance(value, dict):
        items = list(value.items())
        kept = {str(k): _shallow(v, depth - 1) if depth else "..." for k, v in items[:4]}
        return {**kept, "...": f"{len(items) - 4} more"} if len(items) > 4 else kept
    if isinstance(value, list):
        kept_list = [_shallow(v, depth - 1) if depth else "..." for v in value[:4]]
        return [*kept_list, f"... {len(value) - 4} more"] if len(value) > 4 else kept_list
    return value


#: fields whose values a 422 never quotes (a webhook's signing secret, a token, a password)


def _unquoted(loc: tuple, value: Any) -> Any:
    """``value`` with any secret in it masked: the whole value when ``loc`` names a secret
    field, else each secret field of a dict (a body-level error quotes the whole body)."""
    if any(part in SECRET_FIELDS for part in loc):
        return "***"
    if isinstance(value, dict):
        return {k: "***" if k in SECRET_FIELDS else v for k, v in value.items()}
    return value


def _for_a_browser(request: Request) -> bool:
    """A page asked for by a browser (it accepts HTML), not the API nor a script's fetch."""
    path = request.url.path
    return not path.startswith(("/api/", "/static/")) and "text/html" in request.headers.get(
        "accept", ""
    )


def _a_page(request: Request) -> bool:
    """An address whose answer is a page: one of the UI's HTML routes, whoever asks (a trial's
    curl of /executions/abc met pydantic's JSON), or any but the API's asked for by a browser."""
    route = request.scope.get("route")
    html = isinstance(route, APIRoute) and route.response_class is HTMLResponse
    return html or _for_a_browser(request)


def _invalid_page(request: Request, exc: RequestValidationError) -> Response:
    """A page whose address does not parse: 404 for a path naming nothing (``/executions/abc``),
    else 400 naming the field; a page, not JSON, since a person reads it."""
    first = exc.errors()[0]
    where, field = (tuple(first["loc"]) + ("", ""))[:2]
    given = _excerpt(_unquoted((where, field), first.get("input")))
    if where == "path":
        thing = str(field).removesuffix("_id").replace("_", " ")
        return problem(request, NotFound(f"there is no {thing} {given!r}"))
    return problem(request, BadRequest(f"{field}: {error_words(first)} (given: {given!r})"))


#: how many errors a 422 lists; the rest are counted in one last entry (a 1 MB import of 200,000
#: bad values answered 30.9 MB, listing each)
MAX_ERRORS = 20


async def _invalid(request: Request, exc: Exception) -> Response:
    """FastAPI's 422, listing the first `MAX_ERRORS` errors (then "and N more errors"), quoting
    no more than a short excerpt of each input at fault, and never a secret; for a page, the
    error page (`_invalid_page`)."""
    assert isinstance(exc, RequestValidationError)
    if _a_page(request):
        return _invalid_page(request, exc)
    found = exc.errors()
    errors = [
        {
            **error,
            # a key in the path is input too: a 100,000-character parameter name was quoted
            # whole (a probe's 422 was 100 kB)
            "loc": [_excerpt(part) if isinstance(part, str) else part for part in error["loc"]],
            "msg": error_words(error),
            "input": _excerpt(_unquoted(tuple(error["loc"]), error.get("input"))),
        }
        for error in found[:MAX_ERRORS]
    ]
    if len(found) > MAX_ERRORS:
        more = len(found) - MAX_ERRORS
        errors.append(
            {"type": "too_many_errors", "loc": [], "msg": f"and {more} more errors", "input": None}
        )
    return JSONResponse(
        {"detail": jsonable_encoder(errors, custom_encoder={float: _excerpt})}, status_code=422
    )


async def _service_error(request: Request, exc: Exception) -> Response:
    """The service's refusal with its status: JSON, or the error page for a page."""
    assert isinstance(exc, ServiceError)
    if _a_page(request):
        return problem(request, exc)
    return JSONResponse({"detail": exc.detail}, status_code=exc.status_code)


def app_from_environment() -> FastAPI:
    """What each API process of `redline server --workers N` serves (uvicorn's app factory):
    settings and logging from the environment, as the parent's were."""
    from redline.server.core.logs import configure

    settings = get_settings()
    configure(settings.log_json)
    return create_app(settings)


def _warm() -> None:
    """Load scipy.stats, which the detectors import where they run (`redline.detect`): the
    first comparison a page or the API makes would otherwise wait for it (0.5-0.7 s; a trial's
    first compare page took 1.7 s, the later ones under 0.2 s)."""
    importlib.import_module("scipy.stats")


@asynccontextmanager
async def _lifespan(_app: FastAPI) -> AsyncIterator[None]:
    """Startup: the slow imports loaded beside the first requests, not in their way."""
    threading.Thread(target=_warm, name="redline-warm", daemon=True).start()
    yield


def _warn_of_weak_settings(settings: Settings) -> None:
    """Say at start what weakens the service and is left as set (refusing it would stop a
    running deployment at its next restart): a webhook secret short enough to guess, which
    would let anyone report revisions by webhook (a component's own one is refused so)."""
    if settings.webhook_secret and len(settings.webhook_secret) < SECRET_LENGTH:
        logging.getLogger(__name__).warning(
            "REDLINE_WEBHOOK_SECRET has %d characters: a secret that short can be guessed, and "
            "whoever guesses it reports revisions by webhook; use %d or more (python3 -c "
            "'import secrets; print(secrets.token_urlsafe(24))')",
            len(settings.webhook_secret),
            SECRET_LENGTH,
        )


def create_app(settings: Settings | None = None) -> FastAPI:
    """The Redline server; ``settings`` default to the environment (``REDLINE_*``).

    The database must already be migrated (``redline.server.db.migrate``).
    """
    settings = settings or get_settings()
    _warn_of_weak_settings(settings)
    app = FastAPI(
        title="Redline",
        version="1",
        summary="Performance regressions, per revision",
        lifespan=_lifespan,
        docs_url=None,  # served from Redline's own files (`api_docs`), not a CDN
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.tasks = TaskSender(settings)
    app.add_exception_handler(ServiceError, _service_error)
    app.add_exception_handler(DataError, _unstorable)
    app.add_exception_handler(RequestValidationError, _invalid)
    app.add_exception_handler(StarletteHTTPException, _no_route)
    for down in health.DATABASE_DOWN:  # 503 with a message, never a 500, while Postgres is away
        app.add_exception_handler(down, health.database_unavailable)
    # inside the metrics middleware, whose own reads of the request must not meet the limit
    app.add_middleware(BodyLimit, settings=settings)
    metrics.install(app, settings)
    app.add_middleware(HeadAsGet)  # outermost: every layer inside sees the GET it answers
    for module in (
        health,
        components,
        revisions,
        agent,
        jobs,
        webhooks,
        tokens,
        series,
        executions,
        imports,
        regressions,
        alerts,
        learning,
    ):
        app.include_router(module.router)
    api_docs.mount(app)
    web.mount(app, settings)
    return app
