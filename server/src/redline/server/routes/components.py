"""/api/v1/components: components, and what was measured for each."""

from __future__ import annotations

from fastapi import APIRouter, Depends, status
from redline.server.api.deps import SessionDep, require
from redline.server.schemas import (
    ChangeOut,
    ComponentCreate,
    ComponentOut,
    Problem,
    RevisionDetail,
    RevisionOut,
    SeriesOut,
)
from redline.server.services import components, results, revisions

router = APIRouter(prefix="/api/v1/components", tags=["components"])
NOT_FOUND = {404: {"model": Problem, "description": "unknown component or revision"}}


@router.post("", status_code=status.HTTP_201_CREATED, dependencies=[Depends(require("admin"))],
             responses={409: {"model": Problem}})
def create_component(data: ComponentCreate, session: SessionDep) -> ComponentOut:
    return ComponentOut.model_validate(components.create_component(session, data))


@router.get("")
def list_components(session: SessionDep) -> list[ComponentOut]:
    return [ComponentOut.model_validate(c) for c in components.list_components(session)]


@router.get("/{name}/revisions", responses=NOT_FOUND)
def list_revisions(name: str, session: SessionDep) -> list[RevisionOut]:
    """The component's revisions in sort-key order, each with a state derived from its jobs."""
    return revisions.list_revisions(session, name)


@router.get("/{name}/revisions/{title}", responses=NOT_FOUND)
def revision_detail(name: str, title: str, session: SessionDep) -> RevisionDetail:
    return revisions.revision_detail(session, name, title)


@router.get("/{name}/series", responses=NOT_FOUND)
def list_series(name: str, session: SessionDep) -> list[SeriesOut]:
    return results.component_series(session, name)


@router.get("/{name}/changes", responses=NOT_FOUND)
def list_changes(name: str, session: SessionDep, flagged: bool = False) -> list[ChangeOut]:
    """Detected changes; ``?flagged=true`` keeps only those the detector flagged."""
    return results.component_changes(session, name, flagged_only=flagged)
