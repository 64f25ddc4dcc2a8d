"""/api/v1/revisions: CI reports a new revision of a component."""

from __future__ import annotations

from fastapi import APIRouter, Depends, status
from redline.server.api.deps import SessionDep, require
from redline.server.core.bodies import JsonRoute
from redline.server.schemas.common import Problem
from redline.server.schemas.revisions import RevisionCreate, RevisionCreated
from redline.server.services.revisions import create_revision

router = APIRouter(prefix="/api/v1/revisions", tags=["revisions"], route_class=JsonRoute)


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    dependencies=[Depends(require("ci"))],
    responses={404: {"model": Problem}, 409: {"model": Problem}},
)
def report_revision(data: RevisionCreate, session: SessionDep) -> RevisionCreated:
    """Record the revision and queue one job per execution the component asks for."""
    revision = create_revision(session, data)
    return RevisionCreated(revision_id=revision.id, job_ids=[job.id for job in revision.jobs])
