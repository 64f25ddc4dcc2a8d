"""/api/v1/series/{id}: one series' summaries, execution by execution."""

from __future__ import annotations

from fastapi import APIRouter
from redline.server.api.deps import READ, SessionDep
from redline.server.core.bodies import JsonRoute
from redline.server.schemas.common import Problem
from redline.server.schemas.results import SeriesDetail
from redline.server.services import read

router = APIRouter(
    prefix="/api/v1/series", tags=["series"], dependencies=READ, route_class=JsonRoute
)


@router.get("/{series_id}", responses={404: {"model": Problem}})
def get_series(series_id: int, session: SessionDep) -> SeriesDetail:
    """The series' identity and every execution's statistics of it, in sort-key order."""
    return read.series_detail(session, series_id)
