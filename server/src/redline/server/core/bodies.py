"""What a request body may be: its size by kind of route, and, for JSON, its depth and its text.

Every body is limited before it is read whole (`BodyLimit`): a declared ``Content-Length`` over
the limit is refused at once, and a body without one is counted as it streams in. JSON is parsed
in one place (`parse_json`, used by every route through `JsonRoute` and by the routes that read
raw bodies) so that a document nested deeper than `MAX_DEPTH` or holding a lone surrogate or a NUL
(text no database can store) is a 4xx naming the fault and where it is, never a 500.
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Callable, Coroutine
from typing import Any

import numpy as np
from fastapi import HTTPException, Request, Response
from fastapi.dependencies.models import Dependant
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from redline.server.core.config import Settings
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: Deepest JSON nesting accepted: GitHub's and GitLab's pushes and LNT's reports need under ten;
#: far deeper documents would break the recursive code that reads them back (pages, the API).
MAX_DEPTH = 32

_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"')  # a JSON string, escapes included
_NOT_BRACKETS = bytes(b for b in range(256) if b not in b"[]{}")
_SURROGATE_ESCAPE = re.compile(rb"\\u[dD][89a-fA-F]")  # \ud800-\udfff, paired or not
_NUL_ESCAPE = re.compile(rb"\\u0000")


class BadJson(ValueError):
    """A body that is not acceptable JSON; the message says why and, where it can, where."""


def _depth(body: bytes) -> int:
    """The deepest nesting of a valid JSON document, counted on its bytes (no recursion)."""
    marks = _STRING.sub(b"", body).translate(None, delete=_NOT_BRACKETS)
    if not marks:
        return 0
    opens = np.frombuffer(marks, dtype=np.uint8)
    steps = np.where((opens == ord("[")) | (opens == ord("{")), 1, -1)
    return int(np.cumsum(steps).max())


def _shown(key: str) -> str:
    return key.encode("utf-8", "backslashreplace").decode()


def _is_lone_surrogate(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return True
    return False


def _has_nul(text: str) -> bool:
    return "\x00" in text


def _where(value: Any, bad: Callable[[str], bool], path: str = "$") -> str | None:
    """Where in ``value`` a string (or key) is ``bad``, e.g. ``$.results[0].case``."""
    if isinstance(value, str):
        return path if bad(value) else None
    if isinstance(value, list):
        for index, item in enumerate(value):
            if (found := _where(item, bad, f"{path}[{index}]")) is not None:
                return found
    elif isinstance(value, dict):
        for key, item in value.items():
            where = f"{path}.{_shown(key)}"
            if (
                found := _where(key, bad, f"{where} (its name)") or _where(item, bad, where)
            ) is not None:
                return found
    return None


def _whole_number(text: str) -> int:
    """A JSON integer; one longer than Python reads (`sys.get_int_max_str_digits`) refused in
    words a client can act on (a trial's 5,000-digit sort key got Python's own advice)."""
    digits, limit = len(text.lstrip("-")), sys.get_int_max_str_digits()
    if limit and digits > limit:
        raise BadJson(f"a number of {digits} digits, more than {limit}: give it as text")
    return int(text)


def parse_json(body: bytes) -> Any:
    """The JSON document in ``body``; `BadJson` naming the fault when it is malformed, nested
    deeper than `MAX_DEPTH`, or holds a lone surrogate (``"\\ud800"``) or a NUL (``"\\u0000"``),
    which no database text holds."""
    try:
        value = json.loads(body, parse_int=_whole_number)
    except RecursionError:
        raise BadJson(f"JSON nested deeper than {MAX_DEPTH} levels") from None
    except ValueError as exc:  # JSONDecodeError, invalid UTF-8, an over-long integer
        raise BadJson(f"not valid JSON: {exc}") from None
    if _depth(body) > MAX_DEPTH:
        raise BadJson(f"JSON nested deeper than {MAX_DEPTH} levels")
    if _SURROGATE_ESCAPE.search(body) and (where := _where(value, _is_lone_surrogate)):
        raise BadJson(
            f"the string at {where} holds a lone surrogate (\\ud800-\\udfff), which is not text"
        )
    if _NUL_ESCAPE.search(body) and (where := _where(value, _has_nul)):
        raise BadJson(f"the string at {where} holds a NUL character (\\u0000), which no text holds")
    return value


class JsonRequest(Request):
    """A request whose ``json()`` is `parse_json`: a bad document is a 422 naming its fault, in
    the shape of FastAPI's own answer to malformed JSON."""

    async def json(self) -> Any:
        if not hasattr(self, "_json"):
            try:
                self._json = parse_json(await self.body())
            except BadJson as exc:
                raise HTTPException(
                    422, [{"type": "json_invalid", "loc": ["body"], "msg": str(exc), "input": None}]
                ) from None
        return self._json


class JsonRoute(APIRoute):
    """The route class of every router: request bodies are parsed by `parse_json`."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        takes_json = self.body_field is not None
        checks = list(dict.fromkeys(_before_body(self.dependant))) if takes_json else []

        async def handle(request: Request) -> Response:
            for check in checks:
                # the token is checked before the body is read (FastAPI reads it before the
                # checks run): a caller with no token sent 200 MB to the import and was read
                # 35 MB (a trial); one with a made-up token had 32 MiB parsed (an audit)
                try:
                    await run_in_threadpool(check, request)
                except HTTPException as refused:
                    return JSONResponse(
                        {"detail": refused.detail},
                        status_code=refused.status_code,
                        headers=refused.headers,
                    )
            kind = request.headers.get("content-type", "")
            if takes_json and kind and not _is_json(kind):
                # a form-encoded body (curl -d without -H) was "Input should be a valid
                # dictionary", which named nothing the caller could fix (a trial)
                return JSONResponse(
                    {"detail": f"send the body as JSON (Content-Type: application/json), "
                               f"not {kind[:100]!r}"},
                    status_code=415,
                )  # fmt: skip
            return await handler(JsonRequest(request.scope, request.receive))

        return handle


def _before_body(dependant: Dependant) -> list[Callable[[Request], None]]:
    """The route's checks to make before its body is read (a ``require``'s token check)."""
    found = []
    for d in dependant.dependencies:
        check = getattr(d.call, "before_body", None)
        found += ([check] if check is not None else []) + _before_body(d)
    return found


def _is_json(content_type: str) -> bool:
    kind = content_type.split(";", 1)[0].strip().lower()
    return kind == "application/json" or kind.endswith("+json")


def body_limit(settings: Settings, path: str) -> tuple[int, str]:
    """The largest body a request to ``path`` may bring, and the setting that says so."""
    if path.startswith("/api/v1/webhooks/"):
        return settings.max_webhook_bytes, "REDLINE_MAX_WEBHOOK_BYTES"
    if path.startswith("/api/v1/import/"):
        return settings.max_import_bytes, "REDLINE_MAX_IMPORT_BYTES"
    if path.startswith("/api/v1/jobs/") and path.endswith("/recording"):
        return settings.max_upload_bytes, "REDLINE_MAX_UPLOAD_BYTES"
    return settings.max_json_bytes, "REDLINE_MAX_JSON_BYTES"


class BodyLimit:
    """ASGI middleware: 413 for a body over its route's limit, before it is read whole."""

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app, self.settings = app, settings

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit, setting = body_limit(self.settings, scope["path"])
        detail = f"request body larger than the limit of {limit} bytes ({setting})"
        declared = Headers(scope=scope).get("content-length", "")
        if declared.isdigit() and int(declared) > limit:
            await JSONResponse({"detail": detail}, status_code=413)(scope, receive, send)
            return
        received = 0

        async def limited() -> Message:
            nonlocal received
            message = await receive()
            received += len(message.get("body", b""))
            if received > limit:  # raised where the route reads its body: FastAPI answers it
                raise HTTPException(413, detail)
            return message

        await self.app(scope, limited, send)
