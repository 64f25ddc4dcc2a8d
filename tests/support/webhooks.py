"""Signed push webhooks as GitHub sends them, and what they created."""

from __future__ import annotations

import hashlib
import hmac
import json

from redline.server.db import session_factory
from redline.server.models import Job, Revision
from sqlalchemy import func, select

from tests.support.api import Api

SECRET = "s3cret"
COMMITS = [
    {"id": "a" * 40, "message": "first", "timestamp": "2026-11-20T10:00:00+01:00"},
    {"id": "b" * 40, "message": "second", "timestamp": "2026-11-20T10:00:00+01:00"},
]


def github_push(
    repo: str = "https://github.com/org/builder",
    ref: str = "refs/heads/main",
    commits: list[dict] = COMMITS,
) -> bytes:
    return json.dumps(
        {
            "ref": ref,
            "commits": commits,
            "repository": {"clone_url": repo + ".git", "html_url": repo},
        }
    ).encode()


def send_github(api: Api, body: bytes, secret: str = SECRET, event: str = "push") -> object:
    signature = "sha256=" + hmac.new(secret.encode(), body, hashlib.sha256).hexdigest()
    return api.client.post(
        "/api/v1/webhooks/github",
        content=body,
        headers={
            "X-Hub-Signature-256": signature,
            "X-GitHub-Event": event,
            "Content-Type": "application/json",
        },
    )


def send_gitlab(api: Api, body: bytes, token: str = SECRET) -> object:
    """A GitLab push hook: its token is the secret itself (``X-Gitlab-Token``)."""
    return api.client.post(
        "/api/v1/webhooks/gitlab",
        content=body,
        headers={
            "X-Gitlab-Token": token,
            "X-Gitlab-Event": "Push Hook",
            "Content-Type": "application/json",
        },
    )


def counts(api: Api) -> tuple[int, int]:
    """How many revisions and jobs the database holds."""
    with session_factory(api.settings.database_url)() as session:
        return (
            session.scalar(select(func.count()).select_from(Revision)) or 0,
            session.scalar(select(func.count()).select_from(Job)) or 0,
        )
