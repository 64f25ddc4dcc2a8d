"""Push webhooks (GitHub, GitLab): verify the sender, then one revision per pushed commit.

A delivery names a repository by several URLs; every component whose repository (in any
spelling) and default branch match gets a revision per commit, with jobs for its host pool.
Repeated deliveries create nothing twice: revisions are unique per component and title.
"""

from __future__ import annotations

import hashlib
import hmac
import json
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime

from pydantic import ValidationError
from redline.server.models import Component, Revision
from redline.server.schemas import RevisionCreate
from redline.server.schemas_intake import PushCommit, PushEvent, PushRevision, WebhookResult
from redline.server.services.errors import BadRequest, ServiceError
from redline.server.services.repos import repo_key
from redline.server.services.revisions import new_revision
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

TITLE_LENGTH = 12  # a commit's revision title: its first 12 hex digits


class Unauthorized(ServiceError):
    status_code = 401


Verifier = Callable[[str], bool]  # does this secret authenticate the delivery?


def github_verifier(body: bytes, signature: str | None) -> Verifier:
    """``X-Hub-Signature-256: sha256=<hex HMAC-SHA256 of the raw body>``, compared in constant
    time."""
    given = (signature or "").removeprefix("sha256=").encode()

    def verify(secret: str) -> bool:
        expected = hmac.new(secret.encode(), body, hashlib.sha256).hexdigest().encode()
        return bool(secret) and hmac.compare_digest(expected, given)

    return verify


def gitlab_verifier(token: str | None) -> Verifier:
    """``X-Gitlab-Token`` is the secret itself, compared in constant time."""
    given = (token or "").encode()
    return lambda secret: bool(secret) and hmac.compare_digest(secret.encode(), given)


@dataclass
class Push:
    urls: list[str]
    branch: str | None  # None for tags and other refs
    commits: list[PushCommit]


def parse_push(body: bytes) -> Push:
    try:
        event = PushEvent.model_validate(json.loads(body))
    except (ValueError, ValidationError) as exc:
        raise BadRequest(f"not a push event: {exc}") from None
    urls = [url for repo in (event.repository, event.project) if repo for url in repo.urls()]
    branch = event.ref.removeprefix("refs/heads/") if event.ref.startswith("refs/heads/") else None
    commits = event.commits or ([event.head_commit] if event.head_commit else [])
    return Push(urls, branch, commits)


def _candidates(session: Session, push: Push) -> list[Component]:
    keys = {key for key in map(repo_key, push.urls) if key}
    if not keys or push.branch is None:
        return []
    return list(
        session.scalars(
            select(Component)
            .where(Component.repo_key.in_(keys), Component.branch == push.branch)
            .order_by(Component.name)
        )
    )


def sort_key(commit: PushCommit, index: int, received: datetime) -> str:
    """Commit time (UTC), then the commit's place in the push: ``20261122T021651Z.0002``."""
    when = (commit.timestamp or received).astimezone(UTC)
    return f"{when:%Y%m%dT%H%M%SZ}.{index:04d}"


def _add_revision(session: Session, component: Component, data: RevisionCreate) -> Revision | None:
    """The new revision, or None when the component already has it (a repeated delivery)."""
    try:
        with session.begin_nested():
            revision = new_revision(component, data)
            session.add(revision)
            session.flush()
    except IntegrityError:
        return None
    return revision


def _record(session: Session, components: list[Component], push: Push) -> WebhookResult:
    received = datetime.now(UTC)
    result = WebhookResult(detail="")
    for component in components:
        for index, commit in enumerate(push.commits):
            data = RevisionCreate(
                component=component.name,
                title=commit.id[:TITLE_LENGTH],
                sort_key=sort_key(commit, index, received),
                commit=commit.id,
                branch=push.branch or "",
                message=commit.message[:10_000],
                committed_at=commit.timestamp,
            )
            revision = _add_revision(session, component, data)
            if revision is None:
                result.existing += 1
                continue
            result.created.append(
                PushRevision(
                    component=component.name,
                    revision_id=revision.id,
                    title=revision.title,
                    sort_key=revision.sort_key,
                    job_ids=[job.id for job in revision.jobs],
                )
            )
    session.commit()
    result.detail = (
        f"{len(result.created)} revision(s) created, {result.existing} already known"
        f" for {', '.join(c.name for c in components)}"
    )
    return result


def authenticate_push(
    session: Session, body: bytes, verify: Verifier, default_secret: str
) -> tuple[Push, list[Component]]:
    """The push and the components it is authentically meant for (maybe none).

    Raises Unauthorized when no applicable secret (a matching component's own, else
    ``default_secret``) authenticates the delivery, BadRequest when an authentic body is not a
    push event.
    """
    try:
        push = parse_push(body)
    except BadRequest:
        if not verify(default_secret):
            raise Unauthorized("webhook signature does not match") from None
        raise
    candidates = _candidates(session, push)
    secrets = {c.webhook_secret or default_secret for c in candidates} or {default_secret}
    if not any(verify(secret) for secret in secrets):
        raise Unauthorized(
            "webhook signature does not match"
            if any(secrets)
            else "no webhook secret is configured"
        )
    return push, [c for c in candidates if verify(c.webhook_secret or default_secret)]


def receive_push(
    session: Session, body: bytes, verify: Verifier, default_secret: str, event: str = "push"
) -> tuple[bool, WebhookResult]:
    """Authenticate and record a push; returns whether anything was recorded, and the result.

    Events other than ``push`` are authenticated and acknowledged, never recorded.
    """
    push, matched = authenticate_push(session, body, verify, default_secret)
    if event != "push":
        return False, WebhookResult(detail=f"event {event!r} ignored")
    if not matched:
        where = f"branch {push.branch!r}" if push.branch else "this ref (not a branch)"
        repo = push.urls[0] if push.urls else "?"
        return False, WebhookResult(detail=f"no component matches repository {repo!r} and {where}")
    return True, _record(session, matched, push)
