"""HEAD answered as GET without the body, on every address that answers GET (RFC 9110 9.3.2).

FastAPI's routes take only the methods they name: a trial's `curl -I` of a page that exists
got 404 ("there is no page"), of `/healthz` 405, which uptime and link checkers read as down.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send


class HeadAsGet:
    """ASGI middleware: a HEAD request goes on as a GET, and its answer's body is left out (its
    headers, `Content-Length` among them, are the GET's)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return

        async def headers_only(message: Message) -> None:
            if message["type"] == "http.response.body":
                message = {**message, "body": b""}
            await send(message)

        # a copy: the server keeps its own scope, and with it that the answer has no body
        await self.app({**scope, "method": "GET"}, receive, headers_only)
