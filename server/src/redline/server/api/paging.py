"""The query parameters and the header of a paged list (`redline.server.services.paging`)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Query, Response

PageSize = Annotated[int | None, Query(ge=1, le=1000, description="page size")]
Cursor = Annotated[
    str | None, Query(max_length=2000, description="X-Next-Cursor of the previous page")
]


def next_page(response: Response, cursor: str | None) -> None:
    """Announce the next page of a full one in the ``X-Next-Cursor`` header."""
    if cursor is not None:
        response.headers["X-Next-Cursor"] = cursor
