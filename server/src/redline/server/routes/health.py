"""/healthz, and the answer every route gives while the database cannot be reached: 503, not 500.

/healthz asks the database and the task queue's Redis. Without the database nothing works (503);
without the queue the API still takes uploads and reports, which are queued once it is back (the
periodic re-queue), so the service is "degraded" (200: a load balancer keeps it), and says why."""

from __future__ import annotations

import logging

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel
from redline.server.api.deps import SettingsDep
from redline.server.core.bodies import JsonRoute
from redline.server.core.config import Settings
from redline.server.core.tasks import redis_client
from redline.server.db import get_engine
from sqlalchemy import exc, text
from starlette.concurrency import run_in_threadpool

router = APIRouter(tags=["health"], route_class=JsonRoute)
log = logging.getLogger(__name__)

#: Errors meaning "no database to talk to" (refused, shut down, pool exhausted), not a bad query.
DATABASE_DOWN: tuple[type[Exception], ...] = (
    exc.OperationalError,
    exc.InterfaceError,
    exc.TimeoutError,
)
RETRY_AFTER_S = "5"


class Health(BaseModel):
    status: str  # ok, degraded (no queue) or unavailable (no database)
    database: str
    queue: str


def _reason(error: BaseException) -> str:
    orig = getattr(error, "orig", None) or error
    lines = str(orig).strip().splitlines()
    return lines[0] if lines else type(orig).__name__


async def database_unavailable(request: Request, error: Exception) -> JSONResponse:
    """The app's handler for DATABASE_DOWN: agents keep their recordings and try again. The
    cause goes to the log too (a trial's 503 left only its access line there). A value over
    one of Postgres's limits (SQLSTATE class 54, "program limit exceeded": an index row over
    2,704 bytes) is the request's fault, which psycopg raises as an OperationalError too: 422,
    where a retry would fail the same way (a probe was told to try again later)."""
    if str(getattr(getattr(error, "orig", None), "sqlstate", "") or "").startswith("54"):
        log.warning(
            "%s %s: 422, over a limit: %s", request.method, request.url.path, _reason(error)
        )
        return JSONResponse(
            {"detail": f"a value of the request is too large to store ({_reason(error)})"},
            status_code=422,
        )
    log.warning("%s %s: 503, the database: %s", request.method, request.url.path, _reason(error))
    return JSONResponse(
        {"detail": f"the database is unavailable ({_reason(error)}); try again later"},
        status_code=503,
        headers={"Retry-After": RETRY_AFTER_S},
    )


def _ping(database_url: str) -> str:
    try:
        with get_engine(database_url).connect() as connection:
            connection.execute(text("SELECT 1"))
    except DATABASE_DOWN as error:
        return f"unavailable: {_reason(error)}"
    return "ok"


def _ping_queue(settings: Settings) -> str:
    try:
        with redis_client(settings) as client:
            client.ping()
    except Exception as error:  # refused, timed out, a socket gone: each is "away"
        return f"unavailable: {_reason(error)}"
    return "ok"


@router.get(
    "/healthz",
    response_model=Health,
    responses={503: {"model": Health, "description": "no database"}},
)
async def healthz(settings: SettingsDep) -> Health | Response:
    """Liveness, and the database's and the task queue's state: 503 while the database cannot be
    reached; "degraded" (200) while only the queue cannot (uploads are kept and queued later)."""
    database = await run_in_threadpool(_ping, settings.database_url)
    queue = await run_in_threadpool(_ping_queue, settings)
    if database != "ok":
        return JSONResponse(
            Health(status="unavailable", database=database, queue=queue).model_dump(),
            status_code=503,
            headers={"Retry-After": RETRY_AFTER_S},
        )
    return Health(status="ok" if queue == "ok" else "degraded", database=database, queue=queue)
