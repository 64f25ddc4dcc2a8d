"""/api/v1/executions/{id}: one execution of a revision's suite."""

from __future__ import annotations

from fastapi import APIRouter
from redline.server.api.deps import READ, SessionDep
from redline.server.core.bodies import JsonRoute
from redline.server.schemas.common import Problem
from redline.server.schemas.results import ExecutionDetail
from redline.server.services import read

router = APIRouter(
    prefix="/api/v1/executions", tags=["executions"], dependencies=READ, route_class=JsonRoute
)


@router.get("/{execution_id}", responses={404: {"model": Problem}})
def get_execution(execution_id: int, session: SessionDep) -> ExecutionDetail:
    """Where it ran, its recording's hash and size, its metadata, and whether it was pruned."""
    return read.execution_detail(session, execution_id)
