"""/api/v1/revisions: CI reports a new revision of a component."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Response, status
from redline.server.api.deps import CiToken, SessionDep, ensure_component, require_ci
from redline.server.core.bodies import JsonRoute
from redline.server.schemas.common import Problem
from redline.server.schemas.revisions import RevisionCreate, RevisionCreated
from redline.server.services.revision_reports import (
    labels_warning,
    remotes_warning,
    report_revision,
)

router = APIRouter(prefix="/api/v1/revisions", tags=["revisions"], route_class=JsonRoute)


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    dependencies=[Depends(require_ci)],
    responses={
        200: {"model": RevisionCreated, "description": "reported before: the same commit"},
        403: {"model": Problem, "description": "a token bound to other components"},
        404: {"model": Problem},
        409: {"model": Problem},
    },
)
def report(
    data: RevisionCreate, session: SessionDep, response: Response, token: CiToken
) -> RevisionCreated:
    """Record the revision and queue one job per execution the component asks for; a report
    of a revision already known with the same commit and sort key answers 200 with it (a
    re-run CI pipeline must not fail), of another commit 409. A token bound to components
    reports theirs only (403); one not an admin's names the commit by its hash (422: a branch
    or tag moves)."""
    ensure_component(token, data.component)
    revision, created = report_revision(session, data, admin="admin" in token.scopes)
    if not created:
        response.status_code = status.HTTP_200_OK
    return RevisionCreated(
        revision_id=revision.id,
        title=revision.title,
        job_ids=[job.id for job in revision.jobs],
        warning="; ".join(
            said
            for said in (
                remotes_warning(revision.component, data.remotes),
                labels_warning(session, revision.component),
            )
            if said
        ),
    )
