"""A value over one of Postgres's limits is the request's fault (422), not an outage (503)."""

from __future__ import annotations

import asyncio
import json

import psycopg.errors
from redline.server.routes.health import database_unavailable
from sqlalchemy import exc
from starlette.requests import Request

REQUEST = Request(
    {"type": "http", "method": "POST", "path": "/api/v1/import/results", "headers": []}
)


def _answer(orig: Exception) -> tuple[int, dict]:
    error = exc.OperationalError("INSERT INTO series ...", {}, orig)
    response = asyncio.run(database_unavailable(REQUEST, error))
    return response.status_code, json.loads(response.body)


def test_an_index_row_too_large_is_422_naming_it_and_an_outage_stays_503():
    status, body = _answer(
        psycopg.errors.ProgramLimitExceeded("index row size 4520 exceeds btree maximum 2704")
    )
    assert status == 422
    assert body["detail"] == (
        "a value of the request is too large to store (index row size 4520 exceeds btree "
        "maximum 2704)"
    )
    status, body = _answer(psycopg.OperationalError("connection refused"))
    assert status == 503 and "try again later" in body["detail"]
