"""/api/v1/components/{name}/: regressions and their triage, accuracy, detections, detection
configuration and re-analysis."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Query, Request, Response, status
from redline.server.api.deps import READ, SessionDep, TriageToken, ensure_component, require
from redline.server.api.paging import Cursor, PageSize, next_page
from redline.server.core.bodies import JsonRoute
from redline.server.models import Component, RegressionState
from redline.server.schemas.common import Responses, problems
from redline.server.schemas.regressions import (
    AccuracyOut,
    DetectionConfigIn,
    DetectionConfigOut,
    DetectionOut,
    ReanalysisOut,
    RegressionDetail,
    RegressionEventOut,
    RegressionOut,
    TriageRequest,
)
from redline.server.services import detection_config, regressions
from redline.server.services.components import get_component
from sqlalchemy.orm import Session

router = APIRouter(prefix="/api/v1/components", tags=["regressions"], route_class=JsonRoute)
NOT_FOUND = problems(404, description="unknown component or regression")
BAD: Responses = {**problems(400), **NOT_FOUND}


@router.get("/{name}/regressions", responses=BAD, dependencies=READ)
def list_regressions(
    name: str,
    session: SessionDep,
    response: Response,
    state: RegressionState | Literal["open"] | None = None,
    confirmation: Literal["suspected", "confirmed", "not_confirmed", "withdrawn", "standing", "all"]
    | None = None,
    method: str | None = None,
    limit: PageSize = None,
    cursor: Cursor = None,
) -> list[RegressionOut]:
    """Flagged changes for the worse grouped by overlapping revision ranges, newest first;
    ``?state=`` (triage; ``open``: new, acknowledged or confirmed, and standing), ``?confirmation=``
    (suspected until the later revisions confirm it or not; ``standing``: suspected or
    confirmed; ``all``, as the page offers it: every one, the withdrawn too) and ``?method=``
    (a method that flagged a
    change in it) filter. Paged with ``limit``: a full page carries ``X-Next-Cursor``, passed
    back as ``cursor`` for the next; without ``limit``, all."""
    found, following = regressions.list_regressions(
        session, name, state, confirmation, limit, cursor, method
    )
    next_page(response, following)
    return found


@router.get("/{name}/regressions/{regression_id}", responses=NOT_FOUND, dependencies=READ)
def get_regression(name: str, regression_id: int, session: SessionDep) -> RegressionDetail:
    return regressions.regression_detail(session, name, regression_id)


@router.patch("/{name}/regressions/{regression_id}", responses=BAD)
def triage_regression(
    name: str,
    regression_id: int,
    change: TriageRequest,
    session: SessionDep,
    token: TriageToken,
) -> RegressionDetail:
    """Set the triage state (``triage`` or ``admin`` scope; a token bound to components, of
    theirs only); recorded in the history."""
    ensure_component(token, name)
    return regressions.triage(session, name, regression_id, change, token.name)


@router.get("/{name}/regressions/{regression_id}/history", responses=NOT_FOUND, dependencies=READ)
def regression_history(
    name: str, regression_id: int, session: SessionDep
) -> list[RegressionEventOut]:
    return regressions.regression_detail(session, name, regression_id).history


@router.get("/{name}/accuracy", responses=NOT_FOUND, dependencies=READ)
def method_accuracy(name: str, session: SessionDep) -> AccuracyOut:
    """Each method's precision so far, with triage labels as ground truth."""
    return regressions.accuracy(session, name)


@router.get("/{name}/detections", responses=BAD, dependencies=READ)
def list_detections(
    name: str,
    session: SessionDep,
    response: Response,
    revision: str | None = None,
    method: str | None = None,
    limit: Annotated[int, Query(ge=1, le=10_000)] = 1000,
    cursor: Cursor = None,
) -> list[DetectionOut]:
    """Every method's verdict per series, "not enough data" with its reason included; newest
    revision first, flagged first within it. Paged: a full page carries ``X-Next-Cursor``,
    passed back as ``cursor`` for the next."""
    found, following = regressions.list_detections(session, name, revision, method, limit, cursor)
    next_page(response, following)
    return found


@router.get("/{name}/detection-config", responses=NOT_FOUND, dependencies=READ)
def get_detection_config(name: str, session: SessionDep) -> DetectionConfigOut:
    return detection_config.get_config(session, name)


@router.put("/{name}/detection-config", responses=BAD, dependencies=[Depends(require("admin"))])
def put_detection_config(
    name: str, data: DetectionConfigIn, request: Request, session: SessionDep
) -> DetectionConfigOut:
    """Store the configuration, every field left out at its default; with ``reanalyze``
    (default) the history is analysed again."""
    component = detection_config.set_config(session, name, data)
    return _stored(name, component, data, request, session)


@router.patch("/{name}/detection-config", responses=BAD, dependencies=[Depends(require("admin"))])
def patch_detection_config(
    name: str, data: DetectionConfigIn, request: Request, session: SessionDep
) -> DetectionConfigOut:
    """Change only the fields given (``thresholds`` per method and parameter), the rest as
    stored; with ``reanalyze`` (default) the history is analysed again."""
    component = detection_config.patch_config(session, name, data)
    return _stored(name, component, data, request, session)


def _stored(
    name: str, component: Component, data: DetectionConfigIn, request: Request, session: Session
) -> DetectionConfigOut:
    if data.reanalyze:
        detection_config.request_reanalysis(session, component)
        request.app.state.tasks.reanalyze(component.id)
    return detection_config.get_config(session, name)


@router.post(
    "/{name}/reanalysis",
    status_code=status.HTTP_202_ACCEPTED,
    responses=NOT_FOUND,
    dependencies=[Depends(require("admin"))],
)
def start_reanalysis(name: str, request: Request, session: SessionDep) -> ReanalysisOut:
    """Queue a background re-analysis of every revision; progress at GET."""
    component = get_component(session, name)
    detection_config.request_reanalysis(session, component)
    request.app.state.tasks.reanalyze(component.id)
    return detection_config.reanalysis_status(session, name)


@router.get("/{name}/reanalysis", responses=NOT_FOUND, dependencies=READ)
def reanalysis_progress(name: str, session: SessionDep) -> ReanalysisOut:
    return detection_config.reanalysis_status(session, name)
