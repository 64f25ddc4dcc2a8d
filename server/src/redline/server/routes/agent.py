"""/api/v1/agent: performance hosts register and lease jobs (docs/contracts-agent-server.md)."""

from __future__ import annotations

import asyncio
import time
from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request, Response, status
from redline.server.api.deps import (
    AgentToken,
    SessionDep,
    SettingsDep,
    ensure_own_host,
    ensure_own_labels,
    require_agent,
    token_labels,
)
from redline.server.core.bodies import JsonRoute
from redline.server.core.config import Settings
from redline.server.db import session_factory
from redline.server.schemas.common import Problem
from redline.server.schemas.jobs import HostRequest, LeasedJob, RegisterRequest, RegisterResponse
from redline.server.services import jobs
from starlette.concurrency import run_in_threadpool

router = APIRouter(
    prefix="/api/v1/agent",
    tags=["agent"],
    dependencies=[Depends(require_agent)],
    route_class=JsonRoute,
)

MAX_WAIT_S = 60
#: How often a waiting lease looks at the queue again: one cheap query per waiting agent.
RECHECK_S = 0.5


@router.post("/register")
def register(data: RegisterRequest, session: SessionDep, token: AgentToken) -> RegisterResponse:
    ensure_own_host(token, data.name)
    ensure_own_labels(token, data.labels)
    return RegisterResponse(host_id=jobs.register_host(session, data).id)


def _lease_once(
    settings: Settings, host: str, allowed: list[str] | None, components: list[str]
) -> LeasedJob | None:
    """A job for ``host`` with the labels its token may lease with, of its components."""
    with session_factory(settings.database_url)() as session:
        job = jobs.lease_job(
            session, host, settings.lease_seconds, settings.max_attempts, allowed, components
        )
        return None if job is None else jobs.leased_job(job)


def _give_back(settings: Settings, job_id: int, host: str) -> None:
    with session_factory(settings.database_url)() as session:
        jobs.release_job(session, job_id, host)


@router.post(
    "/lease",
    response_model=LeasedJob | None,
    responses={204: {"description": "no job is queued"}, 404: {"model": Problem}},
)
async def lease(
    data: HostRequest,
    request: Request,
    settings: SettingsDep,
    token: AgentToken,
    wait: Annotated[
        int,
        Query(ge=0, le=MAX_WAIT_S, description="seconds to wait for a job before answering 204"),
    ] = 0,
) -> LeasedJob | Response:
    """The next job for this host (newest revision first), leased for ``lease_seconds``.

    With ``wait``, a long poll: the answer comes as soon as a job is queued, or 204 after
    ``wait`` seconds; no database connection is held while waiting. An agent gone before the
    answer is leased nothing: a job leased as it went is given back.
    """
    ensure_own_host(token, data.host)
    bound = (token_labels(token), list(token.components or []))
    deadline = time.monotonic() + wait
    while not await request.is_disconnected():
        job = await run_in_threadpool(_lease_once, settings, data.host, *bound)
        if job is not None and await request.is_disconnected():
            # the agent went away while it was leased: no one would run it before the lease
            # lapsed (a killed agent's long poll kept a job from the next agent for minutes)
            await run_in_threadpool(_give_back, settings, job.id, data.host)
            break
        if job is not None:
            return job
        if time.monotonic() + RECHECK_S > deadline:
            break
        await asyncio.sleep(RECHECK_S)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
