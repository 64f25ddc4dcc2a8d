"""/api/v1/components: components, and what was measured for each."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response, status
from redline.server.api.deps import (
    READ,
    CiToken,
    SessionDep,
    SettingsDep,
    ensure_component,
    require,
    require_ci,
)
from redline.server.api.paging import Cursor, PageSize, next_page
from redline.server.core.bodies import JsonRoute
from redline.server.models import JobState
from redline.server.schemas.common import Problem, problems
from redline.server.schemas.components import ComponentCreate, ComponentOut, ComponentSettings
from redline.server.schemas.results import ChangeOut, Comparison, ExecutionListed, SeriesOut
from redline.server.schemas.revisions import RevisionDetail, RevisionOut, RevisionPatch
from redline.server.services import (
    compare,
    component_deletion,
    components,
    executions,
    read,
    results,
    revision_keys,
    revisions,
)

router = APIRouter(prefix="/api/v1/components", tags=["components"], route_class=JsonRoute)
NOT_FOUND = problems(404, description="unknown component or revision")
BAD = problems(400, 404, description="a bad cursor; an unknown component, revision or host")


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    dependencies=[Depends(require("admin"))],
    responses={409: {"model": Problem}},
)
def create_component(
    data: ComponentCreate, session: SessionDep, settings: SettingsDep
) -> ComponentOut:
    """A component and all its settings; its webhook secret is stored, never shown again."""
    return components.component_out(
        components.create_component(session, data, settings.allow_file_repos)
    )


@router.get("", dependencies=READ)
def list_components(session: SessionDep) -> list[ComponentOut]:
    return [components.component_out(c) for c in components.list_components(session)]


@router.get("/{name}", responses=NOT_FOUND, dependencies=READ)
def get_component(name: str, session: SessionDep) -> ComponentOut:
    return components.component_out(components.get_component(session, name))


@router.patch("/{name}", responses=NOT_FOUND, dependencies=[Depends(require("admin"))])
def update_component(
    name: str, data: ComponentSettings, session: SessionDep, settings: SettingsDep
) -> ComponentOut:
    """Change the settings given; ``"webhook_secret": ""`` returns to REDLINE_WEBHOOK_SECRET."""
    return components.component_out(
        components.update_component(session, name, data, settings.allow_file_repos)
    )


@router.delete(
    "/{name}",
    responses={**NOT_FOUND, **problems(409, description="a job of it is in flight")},
    dependencies=[Depends(require("admin"))],
)
def delete_component(name: str, session: SessionDep) -> dict[str, int | str]:
    """Delete the component and its whole history (revisions, results, verdicts, regressions,
    alerts about it, models, settings) and its files; how many of each went. 409 while a host
    holds one of its jobs or a result waits to be ingested."""
    return {"deleted": name, **component_deletion.delete_component(session, name)}


@router.get("/{name}/revisions", responses=NOT_FOUND, dependencies=READ)
def list_revisions(
    name: str,
    session: SessionDep,
    response: Response,
    limit: PageSize = None,
    cursor: Cursor = None,
) -> list[RevisionOut]:
    """The component's revisions in sort-key order, each with a state derived from its jobs.

    Paged with ``limit``: a full page carries the header ``X-Next-Cursor``; pass it back as
    ``cursor`` for the revisions after it. Without ``limit``, all revisions.
    """
    page = revisions.page_revisions(session, name, limit, cursor)
    if limit is not None and len(page) == limit:
        response.headers["X-Next-Cursor"] = revisions.encode_cursor(page[-1])
    return [revisions.revision_out(revision) for revision in page]


@router.get("/{name}/revisions/{title}", responses=NOT_FOUND, dependencies=READ)
def revision_detail(name: str, title: str, session: SessionDep) -> RevisionDetail:
    return revisions.revision_detail(session, name, title)


@router.patch(
    "/{name}/revisions/{title}", responses=NOT_FOUND, dependencies=[Depends(require("admin"))]
)
def patch_revision(
    name: str, title: str, data: RevisionPatch, request: Request, session: SessionDep
) -> RevisionDetail:
    """Correct a revision's sort key (a CI system's far-future time sorts it above every later
    revision); the component's history is judged again in the new order. 409 while a regression
    begins or ends at it or confirmation runs of it have not ended (`revision_keys`)."""
    component = revision_keys.set_sort_key(session, name, title, data.sort_key)
    if not request.app.state.tasks.reanalyze(component.id):
        raise HTTPException(
            status.HTTP_503_SERVICE_UNAVAILABLE,
            "the key is corrected, but the re-analysis that judges the history in the new order "
            f"could not be sent (the queue is unreachable): POST /api/v1/components/{name}/"
            "reanalysis once it is back",
        )
    return revisions.revision_detail(session, name, title)


@router.post(
    "/{name}/revisions/{title}/cancel", responses=NOT_FOUND, dependencies=[Depends(require_ci)]
)
def cancel_revision(name: str, title: str, session: SessionDep, token: CiToken) -> RevisionDetail:
    """Cancel the revision's jobs that have not finished; results already stored stay."""
    ensure_component(token, name)
    return revisions.cancel_revision(session, name, title)


@router.delete(
    "/{name}/revisions/{title}",
    responses={**NOT_FOUND, **problems(409, description="it has results, or a host holds a job")},
    dependencies=[Depends(require("admin"))],
)
def delete_revision(name: str, title: str, session: SessionDep) -> dict[str, int | str]:
    """Delete a revision of which nothing was measured (a commit reported by mistake, say),
    with its jobs. 409 when it has results (they are part of the history later revisions were
    judged against) or while a host holds one of its jobs."""
    return component_deletion.delete_revision(session, name, title)


@router.get("/{name}/executions", responses=BAD, dependencies=READ)
def list_executions(
    name: str,
    session: SessionDep,
    response: Response,
    revision: str | None = None,
    host: str | None = None,
    state: JobState | None = None,
    limit: PageSize = None,
    cursor: Cursor = None,
) -> list[ExecutionListed]:
    """The component's executions (confirmation runs too, with their ``pair``), newest revision
    first; ``?revision=`` (a title), ``?host=`` and ``?state=`` (the job's) filter, an unknown
    revision or host is a 404 naming it. Paged with ``limit``: a full page carries
    ``X-Next-Cursor``, passed back as ``cursor`` for the next; without ``limit``, all."""
    found, following = executions.list_executions(
        session, name, revision, host, state.value if state else None, limit, cursor
    )
    next_page(response, following)
    return found


@router.get("/{name}/series", responses=NOT_FOUND, dependencies=READ)
def list_series(
    name: str,
    session: SessionDep,
    request: Request,
    case: str | None = None,
    phase: str | None = None,
    process: str | None = None,
    counter: str | None = None,
    revisions: Annotated[
        int, Query(ge=1, le=10_000, description="the newest revisions to give points of")
    ] = results.SERIES_REVISIONS,
) -> list[SeriesOut]:
    """The component's series with one point per revision among the newest ``revisions``;
    filtered by ``case``, ``phase``, ``process``, ``counter`` and parameters as
    ``param.NAME=VALUE`` (e.g. ``param.legs=8``)."""
    params = {
        key.removeprefix("param."): value
        for key, value in request.query_params.items()
        if key.startswith("param.")
    }
    fields = {"case": case, "phase": phase, "process": process, "counter": counter}
    found = results.component_series(session, name, fields, revisions)
    return read.filter_series(found, fields, params)


@router.get("/{name}/compare", responses=NOT_FOUND, dependencies=READ)
def compare_revisions(name: str, base: str, candidate: str, session: SessionDep) -> Comparison:
    """Series by series: baseline and candidate statistics, relative change, KS test."""
    return compare.compare(session, name, base, candidate)


@router.get("/{name}/changes", responses=NOT_FOUND, dependencies=READ)
def list_changes(
    name: str,
    session: SessionDep,
    response: Response,
    flagged: bool = False,
    limit: PageSize = None,
    cursor: Cursor = None,
) -> list[ChangeOut]:
    """KS's verdicts, newest revision first, flagged first within it; ``?flagged=true`` keeps
    only those it flagged. Paged with ``limit``: a full page carries ``X-Next-Cursor``, passed
    back as ``cursor`` for the next; without ``limit``, all."""
    found, following = results.component_changes(session, name, flagged, limit, cursor)
    next_page(response, following)
    return found
