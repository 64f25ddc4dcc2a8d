"""/api/v1/webhooks: GitHub and GitLab push events become revisions and jobs."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated

from fastapi import APIRouter, Header, Request, Response, status
from redline.server.api.deps import SettingsDep
from redline.server.core.bodies import JsonRoute
from redline.server.core.config import Settings
from redline.server.db import session_factory
from redline.server.schemas.common import Problem
from redline.server.schemas.webhooks import PushEvent, WebhookResult
from redline.server.services.webhooks import (
    Unauthorized,
    Verifier,
    github_verifier,
    gitlab_verifier,
    receive_push,
)
from starlette.concurrency import run_in_threadpool

router = APIRouter(prefix="/api/v1/webhooks", tags=["webhooks"], route_class=JsonRoute)
RESPONSES: dict[int | str, dict] = {
    202: {
        "model": WebhookResult,
        "description": "nothing to record: no component matches, or not a push event",
    },
    400: {"model": Problem},
    401: {"model": Problem, "description": "bad signature or token"},
}
PUSH_BODY = {
    "requestBody": {
        "required": True,
        "content": {"application/json": {"schema": PushEvent.model_json_schema()}},
    }
}


def _receive(
    settings: Settings, body: bytes, verify: Verifier, event: str
) -> tuple[bool, WebhookResult]:
    with session_factory(settings.database_url)() as session:
        return receive_push(session, body, verify, settings.webhook_secret, event)


def _signed(header: str, given: str | None, provider: str) -> None:
    """Unauthorized naming ``header`` when the delivery does not carry it (a trial's was told
    the signature did not match)."""
    if not given:
        raise Unauthorized(
            f"the {header} header is missing: {provider} sends it once the webhook has a secret "
            "(the component's webhook_secret, else REDLINE_WEBHOOK_SECRET)"
        )


async def _answer(
    request: Request,
    response: Response,
    settings: Settings,
    verify: Callable[[bytes], Verifier],
    event: str,
) -> WebhookResult:
    body = await request.body()
    recorded, result = await run_in_threadpool(_receive, settings, body, verify(body), event)
    if not recorded:
        response.status_code = status.HTTP_202_ACCEPTED
    return result


@router.post("/github", responses=RESPONSES, openapi_extra=PUSH_BODY)
async def github_push(
    request: Request,
    response: Response,
    settings: SettingsDep,
    x_hub_signature_256: Annotated[
        str | None, Header(description="sha256=HMAC-SHA256 of the raw body with the webhook secret")
    ] = None,
    x_github_event: Annotated[str, Header()] = "push",
) -> WebhookResult:
    """A GitHub push: one revision per commit for each component of that repository and
    branch. Other events (``ping``) are authenticated, acknowledged (202) and ignored."""
    _signed("X-Hub-Signature-256", x_hub_signature_256, "GitHub")
    return await _answer(
        request,
        response,
        settings,
        lambda body: github_verifier(body, x_hub_signature_256),
        x_github_event,
    )


@router.post("/gitlab", responses=RESPONSES, openapi_extra=PUSH_BODY)
async def gitlab_push(
    request: Request,
    response: Response,
    settings: SettingsDep,
    x_gitlab_token: Annotated[str | None, Header(description="the webhook secret")] = None,
    x_gitlab_event: Annotated[str, Header()] = "Push Hook",
) -> WebhookResult:
    """A GitLab push hook: one revision per commit for each matching component."""
    _signed("X-Gitlab-Token", x_gitlab_token, "GitLab")
    event = "push" if x_gitlab_event in ("Push Hook", "System Hook") else x_gitlab_event
    return await _answer(
        request, response, settings, lambda _body: gitlab_verifier(x_gitlab_token), event
    )
