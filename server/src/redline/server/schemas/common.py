"""What every error answer of the API looks like, how a route declares the ones it gives, and
what every JSON request body is."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict

#: a route's documented answers besides its success (FastAPI's ``responses=``)
Responses = dict[int | str, dict[str, Any]]


class RequestBody(BaseModel):
    """A JSON request body: a field it does not know is refused (422 naming it), never ignored
    (a misspelt setting would be dropped and its default stored; a trial's triage with a stray
    field was taken)."""

    model_config = ConfigDict(extra="forbid")


class Problem(BaseModel):
    detail: str


def problems(*codes: int, description: str | None = None) -> Responses:
    """The error answers ``codes``, each a `Problem` (with ``description`` when given)."""
    extra = {"description": description} if description else {}
    return {code: {"model": Problem, **extra} for code in codes}
