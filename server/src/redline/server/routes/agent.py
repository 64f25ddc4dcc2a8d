"""/api/v1/agent: performance hosts register and lease jobs (docs/contracts-agent-server.md)."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Response, status
from redline.server.api.deps import SessionDep, SettingsDep, require
from redline.server.schemas import (
    HostRequest,
    LeasedJob,
    Problem,
    RegisterRequest,
    RegisterResponse,
)
from redline.server.services import jobs

router = APIRouter(prefix="/api/v1/agent", tags=["agent"],
                   dependencies=[Depends(require("agent"))])


@router.post("/register")
def register(data: RegisterRequest, session: SessionDep) -> RegisterResponse:
    return RegisterResponse(host_id=jobs.register_host(session, data).id)


@router.post("/lease", response_model=LeasedJob | None,
             responses={204: {"description": "no job is queued"}, 404: {"model": Problem}})
def lease(data: HostRequest, session: SessionDep, settings: SettingsDep) -> LeasedJob | Response:
    """The next job for this host (newest revision first), leased for ``lease_seconds``."""
    job = jobs.lease_job(session, data.host, settings.lease_seconds, settings.max_attempts)
    if job is None:
        return Response(status_code=status.HTTP_204_NO_CONTENT)
    return jobs.leased_job(job)
