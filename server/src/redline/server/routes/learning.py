"""/api/v1/components/{name}/models and /runtime-alerts: resource-usage models trained by a worker
from a component's recordings, their files for `redline watch`, and the alerts it reports."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request, status
from fastapi.responses import FileResponse
from redline.server.api.deps import (
    READ,
    AgentToken,
    SessionDep,
    ensure_component,
    ensure_own_host,
    require,
)
from redline.server.core.bodies import JsonRoute
from redline.server.schemas.common import problems
from redline.server.schemas.learning import ModelOut, ModelRequest, RuntimeAlertIn, RuntimeAlertOut
from redline.server.services import learning

router = APIRouter(prefix="/api/v1/components", tags=["models"], route_class=JsonRoute)
NOT_FOUND = problems(404, description="unknown component or model")


@router.post(
    "/{name}/models",
    status_code=status.HTTP_202_ACCEPTED,
    responses={**NOT_FOUND, **problems(422)},
    dependencies=[Depends(require("admin"))],
)
def request_model(name: str, data: ModelRequest, session: SessionDep, request: Request) -> ModelOut:
    """Train a model of the component's CPU and RSS from the executions named (a worker fits
    it: poll the model until it is done or failed)."""
    row = learning.request_model(session, name, data)
    request.app.state.tasks.train(row.id)
    return learning.model_out(row, name)


@router.get("/{name}/models", responses=NOT_FOUND, dependencies=READ)
def list_models(name: str, session: SessionDep) -> list[ModelOut]:
    return learning.list_models(session, name)


@router.get("/{name}/models/{ident}", responses=NOT_FOUND, dependencies=READ)
def get_model(name: str, ident: int, session: SessionDep) -> ModelOut:
    return learning.model_out(learning.get_model(session, name, ident), name)


@router.get(
    "/{name}/models/{ident}/file",
    responses={**NOT_FOUND, 200: {"content": {"application/octet-stream": {}}}},
    dependencies=READ,
    response_class=FileResponse,
)
def model_file(name: str, ident: int, session: SessionDep) -> FileResponse:
    """The model file, for `redline watch --model` (a pickle: load only your server's)."""
    return FileResponse(
        learning.model_file(session, name, ident),
        media_type="application/octet-stream",
        filename=f"{name}-model-{ident}.joblib",
    )


@router.post(
    "/{name}/runtime-alerts",
    status_code=status.HTTP_201_CREATED,
    responses=NOT_FOUND,
)
def report_alert(
    name: str, data: RuntimeAlertIn, session: SessionDep, request: Request, token: AgentToken
) -> RuntimeAlertOut:
    """A resource fault (or its end) that `redline watch` saw on the running component; the
    alert subscriptions that want its target hear of it. The host is the token's (one given
    must be it, or of its pool: 403 otherwise)."""
    bound = token.host or ""
    data.host = data.host or ("" if bound.endswith("*") else bound)  # a pool's: say which
    ensure_own_host(token, data.host)
    ensure_component(token, name)
    stored = learning.record_alert(session, name, data)
    request.app.state.tasks.runtime_alert(stored.id)
    return stored


@router.get("/{name}/runtime-alerts", responses=NOT_FOUND, dependencies=READ)
def list_alerts(
    name: str, session: SessionDep, limit: Annotated[int, Query(ge=1, le=1000)] = 100
) -> list[RuntimeAlertOut]:
    return learning.list_alerts(session, name, limit)
