"""What every error answer of the API looks like, and how a route declares the ones it gives."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel

#: a route's documented answers besides its success (FastAPI's ``responses=``)
Responses = dict[int | str, dict[str, Any]]


class Problem(BaseModel):
    detail: str


def problems(*codes: int, description: str | None = None) -> Responses:
    """The error answers ``codes``, each a `Problem` (with ``description`` when given)."""
    extra = {"description": description} if description else {}
    return {code: {"model": Problem, **extra} for code in codes}
