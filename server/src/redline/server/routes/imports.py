"""/api/v1/import: history from LNT reports and from benchmarks that do not use the SDK."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request, Response, status
from redline.server.api.deps import CiToken, SessionDep, SettingsDep, ensure_component, require_ci
from redline.server.core.bodies import JsonRoute
from redline.server.schemas.common import Problem
from redline.server.schemas.imports import ImportResult, ResultsImport
from redline.server.services.imports import from_results, store_import
from redline.server.services.lnt import ORDER_FIELD, parse_lnt
from starlette.concurrency import run_in_threadpool

router = APIRouter(
    prefix="/api/v1/import",
    tags=["import"],
    dependencies=[Depends(require_ci)],
    route_class=JsonRoute,
)
RESPONSES: dict[int | str, dict] = {
    200: {"model": ImportResult, "description": "imported before; nothing new stored"},
    400: {"model": Problem},
    403: {"model": Problem, "description": "a ci token's import into a component hosts measure"},
    404: {"model": Problem},
}
LNT_BODY = {
    "requestBody": {
        "required": True,
        "content": {
            "application/json": {
                "schema": {
                    "type": "object",
                    "description": "an LNT report, format_version 2",
                    "required": ["format_version", "machine", "run", "tests"],
                }
            }
        },
    }
}


def _finish(result: ImportResult, request: Request, response: Response) -> ImportResult:
    """201 and detection queued for the revision when created; 200 when imported before."""
    response.status_code = status.HTTP_201_CREATED if result.created else status.HTTP_200_OK
    if result.created:
        request.app.state.tasks.detect(result.revision_id)
    return result


@router.post(
    "/lnt", status_code=status.HTTP_201_CREATED, responses=RESPONSES, openapi_extra=LNT_BODY
)
async def import_lnt(
    request: Request,
    response: Response,
    session: SessionDep,
    settings: SettingsDep,
    token: CiToken,
    component: Annotated[str, Query(description="the Redline component it belongs to")],
    order_field: Annotated[str, Query(description="the run field that orders runs")] = ORDER_FIELD,
) -> ImportResult:
    """One LNT run: each test's metric becomes a series (case = test, counter = metric)."""
    ensure_component(token, component)
    body = await request.body()
    run = parse_lnt(body, component, order_field)
    result = await run_in_threadpool(
        store_import, session, settings.storage_dir, run, body, admin="admin" in token.scopes
    )
    return await run_in_threadpool(_finish, result, request, response)


@router.post("/results", status_code=status.HTTP_201_CREATED, responses=RESPONSES)
def import_results(
    data: ResultsImport,
    request: Request,
    response: Response,
    session: SessionDep,
    settings: SettingsDep,
    token: CiToken,
) -> ImportResult:
    """A benchmark's samples per named series, for one revision (docs/api.md)."""
    ensure_component(token, data.component)
    body = data.model_dump_json().encode()
    admin = "admin" in token.scopes
    stored = store_import(session, settings.storage_dir, from_results(data), body, admin=admin)
    return _finish(stored, request, response)
