"""/api/v1/jobs/{id}: heartbeats, uploads, releases and failures from the agent holding a job."""

from __future__ import annotations

import logging
from typing import Annotated

from fastapi import APIRouter, Depends, Header, Request, Response, status
from redline.server.api.deps import (
    AgentToken,
    SessionDep,
    SettingsDep,
    ensure_component,
    ensure_own_host,
    require_agent,
)
from redline.server.core.bodies import JsonRoute
from redline.server.core.config import Settings
from redline.server.db import session_factory
from redline.server.models import ApiToken
from redline.server.schemas.common import problems
from redline.server.schemas.jobs import (
    FailRequest,
    HeartbeatResponse,
    HostRequest,
    JobStateOut,
    UploadResponse,
)
from redline.server.services import jobs
from redline.server.services.errors import TooLarge
from redline.server.services.uploads import (
    Accepted,
    Staged,
    accept_recording,
    check_before_reading,
    stage_upload,
)
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

log = logging.getLogger(__name__)
router = APIRouter(
    prefix="/api/v1/jobs",
    tags=["jobs"],
    dependencies=[Depends(require_agent)],
    route_class=JsonRoute,
)
PROBLEMS = problems(400, 404, 409, 413)


def ensure_own_job(session: Session, token: ApiToken, job_id: int) -> None:
    """A token bound to components touches their jobs only, 403 otherwise (a pool token bound
    to one component acts for hosts whose other tokens run others' jobs)."""
    if token.components and (name := jobs.component_of_job(session, job_id)) is not None:
        ensure_component(token, name)


@router.post("/{job_id}/heartbeat", responses=PROBLEMS)
def heartbeat(
    job_id: int, data: HostRequest, session: SessionDep, settings: SettingsDep, token: AgentToken
) -> HeartbeatResponse:
    """Extend this host's lease; 409 when the job is no longer leased to it."""
    ensure_own_host(token, data.host)
    ensure_own_job(session, token, job_id)
    job = jobs.heartbeat(session, job_id, data.host, settings.lease_seconds)
    assert job.lease_expires_at is not None
    return HeartbeatResponse(lease_expires_at=job.lease_expires_at)


@router.post("/{job_id}/release", responses=PROBLEMS)
def release(job_id: int, data: HostRequest, session: SessionDep, token: AgentToken) -> JobStateOut:
    """Give the job back to the queue without counting an attempt (the agent is stopping)."""
    ensure_own_host(token, data.host)
    ensure_own_job(session, token, job_id)
    job = jobs.release_job(session, job_id, data.host)
    return JobStateOut(id=job.id, state=job.state.value, reason=job.reason)


@router.post("/{job_id}/fail", responses=PROBLEMS)
def fail(
    job_id: int, data: FailRequest, request: Request, session: SessionDep, token: AgentToken
) -> JobStateOut:
    """Fail the job with the agent's reason; 409 when this host does not hold it."""
    ensure_own_host(token, data.host)
    ensure_own_job(session, token, job_id)
    job, again = jobs.fail_job(session, job_id, data.host, data.reason, data.of_commit)
    if jobs.ended(session, job.revision_id):  # no ingest follows: the verdict is posted now
        request.app.state.tasks.revision_ended(job.revision_id)
    if again:  # a fresh run others waited for: they are judged without it
        request.app.state.tasks.detect(*again)
    return JobStateOut(id=job.id, state=job.state.value, reason=job.reason)


def _check_before_reading(
    settings: Settings, token: ApiToken, job_id: int, claimed: str, host: str
) -> None:
    with session_factory(settings.database_url)() as session:
        ensure_own_job(session, token, job_id)
        check_before_reading(session, job_id, claimed, host)


def _accept(settings: Settings, job_id: int, staged: Staged, claimed: str, host: str) -> Accepted:
    with session_factory(settings.database_url)() as session:
        return accept_recording(
            session,
            settings.storage_dir,
            job_id,
            staged,
            claimed,
            host,
            max_unpacked=settings.max_unpacked_bytes,
        )


@router.put(
    "/{job_id}/recording",
    status_code=status.HTTP_201_CREATED,
    responses={200: {"model": UploadResponse, "description": "already stored"}, **PROBLEMS},
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}
            },
        }
    },
)
async def upload_recording(
    job_id: int,
    request: Request,
    response: Response,
    settings: SettingsDep,
    token: AgentToken,
    x_redline_sha256: Annotated[str, Header(description="sha256 of the body, hex")],
    x_redline_host: Annotated[
        str, Header(min_length=1, max_length=200, description="the host holding the job")
    ],
) -> UploadResponse:
    """Store the job's MCAP recording (raw body) and queue its ingestion; idempotent by hash.

    Only the host holding the job may upload it (409), or resend what it uploaded.
    """
    ensure_own_host(token, x_redline_host)
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > settings.max_upload_bytes:
        raise TooLarge(
            f"recording of {declared} bytes is larger than the limit of "
            f"{settings.max_upload_bytes} bytes"
        )
    await run_in_threadpool(
        _check_before_reading, settings, token, job_id, x_redline_sha256, x_redline_host
    )
    staged = await stage_upload(request.stream(), settings.storage_dir, settings.max_upload_bytes)
    try:
        accepted = await run_in_threadpool(
            _accept, settings, job_id, staged, x_redline_sha256, x_redline_host
        )
    finally:
        staged.path.unlink(missing_ok=True)
    if not accepted.created:
        response.status_code = status.HTTP_200_OK
    queued = accepted.needs_ingest and await run_in_threadpool(
        request.app.state.tasks.ingest, accepted.execution_id
    )
    return UploadResponse(execution_id=accepted.execution_id, ingest_queued=queued)
