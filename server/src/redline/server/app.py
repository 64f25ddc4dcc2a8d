"""The FastAPI application factory."""

from __future__ import annotations

import math

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from redline.server.core import metrics
from redline.server.core.config import Settings, get_settings
from redline.server.routes import (
    agent,
    components,
    executions,
    health,
    imports,
    jobs,
    regressions,
    revisions,
    series,
    tokens,
    web,
    webhooks,
)
from redline.server.services.errors import ServiceError
from redline.worker.app import TaskSender
from sqlalchemy.exc import DataError


async def _unstorable(request: Request, exc: Exception) -> JSONResponse:
    """A value Postgres cannot hold (an id past 2**31, a NUL in a text): the caller's fault."""
    orig = getattr(exc, "orig", None) or exc
    reason = (str(orig).strip().splitlines() or [type(orig).__name__])[0]
    return JSONResponse(
        {"detail": f"a value in the request cannot be stored: {reason}"}, status_code=422
    )


async def _invalid(request: Request, exc: Exception) -> JSONResponse:
    """FastAPI's 422, with a non-finite input (NaN, inf) quoted: JSON has no such numbers."""
    assert isinstance(exc, RequestValidationError)
    finite = {float: lambda value: value if math.isfinite(value) else str(value)}
    return JSONResponse(
        {"detail": jsonable_encoder(exc.errors(), custom_encoder=finite)}, status_code=422
    )


async def _service_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ServiceError)
    return JSONResponse({"detail": exc.detail}, status_code=exc.status_code)


def create_app(settings: Settings | None = None) -> FastAPI:
    """The Redline server; ``settings`` default to the environment (``REDLINE_*``).

    The database must already be migrated (``redline.server.db.migrate``).
    """
    settings = settings or get_settings()
    app = FastAPI(title="Redline", version="1", summary="Performance regressions, per revision")
    app.state.settings = settings
    app.state.tasks = TaskSender(settings)
    app.add_exception_handler(ServiceError, _service_error)
    app.add_exception_handler(DataError, _unstorable)
    app.add_exception_handler(RequestValidationError, _invalid)
    for down in health.DATABASE_DOWN:  # 503 with a message, never a 500, while Postgres is away
        app.add_exception_handler(down, health.database_unavailable)
    metrics.install(app, settings)
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
    ):
        app.include_router(module.router)
    web.mount(app, settings)
    return app
