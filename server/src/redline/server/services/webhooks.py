"""Push webhooks (GitHub, GitLab): verify the sender, then one revision per pushed commit.

A delivery names a repository by several URLs; every component whose repository (in any
spelling) and default branch match gets a revision per commit, with jobs for its host pool.
Repeated deliveries create nothing twice: revisions are unique per component and title.
"""

from __future__ import annotations

import hashlib
import hmac
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime

from pydantic import ValidationError
from redline.recording.format import COMMIT_HASH
from redline.server.core.bodies import BadJson, parse_json
from redline.server.models import Component, Revision
from redline.server.schemas.fields import parse_commit_time
from redline.server.schemas.revisions import RevisionCreate
from redline.server.schemas.webhooks import (
    PushCommit,
    PushEvent,
    PushRevision,
    RefusedCommit,
    WebhookResult,
)
from redline.server.services.components import revision_of_commit, same_commit
from redline.server.services.errors import BadRequest, ServiceError
from redline.server.services.repos import repo_key
from redline.server.services.revision_reports import cannot_run, reports_take_turns
from redline.server.services.revisions import new_revision
from sqlalchemy import exists, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

TITLE_LENGTH = 12  # a commit's revision title: its first 12 hex digits


class Unauthorized(ServiceError):
    status_code = 401


@dataclass(frozen=True)
class Verifier:
    """Whether a secret authenticates the delivery, and what the delivery proves itself with
    (a refusal names it: a trial's wrong GitLab token was told the signature did not match,
    where GitLab sends the secret itself)."""

    check: Callable[[str], bool]
    proof: str = "webhook signature"

    def __call__(self, secret: str) -> bool:
        return self.check(secret)


def github_verifier(body: bytes, signature: str | None) -> Verifier:
    """``X-Hub-Signature-256: sha256=<hex HMAC-SHA256 of the raw body>``, compared in constant
    time."""
    given = (signature or "").removeprefix("sha256=").encode()

    def verify(secret: str) -> bool:
        expected = hmac.new(secret.encode(), body, hashlib.sha256).hexdigest().encode()
        return bool(secret) and hmac.compare_digest(expected, given)

    return Verifier(verify, "webhook signature (X-Hub-Signature-256)")


def gitlab_verifier(token: str | None) -> Verifier:
    """``X-Gitlab-Token`` is the secret itself, compared in constant time."""
    given = (token or "").encode()
    return Verifier(
        lambda secret: bool(secret) and hmac.compare_digest(secret.encode(), given),
        "webhook token (X-Gitlab-Token)",
    )


@dataclass
class Push:
    urls: list[str]
    branch: str | None  # None for tags and other refs
    commits: list[PushCommit]


def parse_push(body: bytes) -> Push:
    try:
        event = PushEvent.model_validate(parse_json(body))
    except BadJson as exc:
        raise BadRequest(f"not a push event: {exc}") from None
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(part) for part in first["loc"]) or "the body"
        raise BadRequest(f"not a push event: {where}: {first['msg']}") from None
    urls = [url for repo in (event.repository, event.project) if repo for url in repo.urls()]
    branch = event.ref.removeprefix("refs/heads/") if event.ref.startswith("refs/heads/") else None
    commits = event.commits or ([event.head_commit] if event.head_commit else [])
    return Push(urls, branch, commits)


def _of_repository(session: Session, push: Push) -> list[Component]:
    """The components of the repository the push names, whatever their branch: their secrets
    authenticate any event of it (a ping too), their branch decides what is recorded."""
    keys = {key for key in map(repo_key, push.urls) if key}
    if not keys:
        return []
    return list(
        session.scalars(
            select(Component).where(Component.repo_key.in_(keys)).order_by(Component.name)
        )
    )


def commit_time(commit: PushCommit) -> datetime | None:
    """The commit's time; ValueError saying what is wrong with the commit otherwise."""
    if not COMMIT_HASH.fullmatch(commit.id):
        raise ValueError(f"id {commit.id[:80]!r} is not a commit hash (7 to 64 hex digits)")
    return parse_commit_time(commit.timestamp) if commit.timestamp else None


def sort_key(when: datetime, index: int) -> str:
    """Commit time in seconds since the epoch, as CI reports it (`git log -1 --format=%ct`,
    docs/ci.md), then the commit's place in the push: ``1795165200.0002``. (A calendar form,
    ``20261122T021651Z``, sorted before every CI-reported revision: a trial's pushed commit came
    before the history CI had reported.)"""
    return f"{int(when.timestamp())}.{index:04d}"


def _add_revision(
    session: Session, component: Component, data: RevisionCreate
) -> Revision | str | None:
    """The new revision, or None when the component already has it (a repeated delivery, or
    CI's report of the commit under its full SHA), or why not when its title is another
    commit's (two commits whose first 12 hex digits agree: a trial's push of 3,000 such ids was
    answered "2999 already known", as if delivered before)."""
    if revision_of_commit(session, component, data.commit) is not None:
        return None
    try:
        with session.begin_nested():
            revision = new_revision(component, data)
            session.add(revision)
            session.flush()
    except IntegrityError:  # its title is taken: by this commit (a delivery meanwhile) or not
        holder = session.scalar(
            select(Revision.commit).where(
                Revision.component_id == component.id, Revision.title == data.title
            )
        )
        if holder is None or same_commit(holder, data.commit):
            return None
        return (
            f"component {component.name!r} already has a revision {data.title!r}, of commit "
            f"{holder!r}: report this commit with a title of its own (POST /api/v1/revisions)"
        )
    return revision


def _record(session: Session, components: list[Component], push: Push) -> WebhookResult:
    """One revision per valid commit and component; a bad commit is refused, not the push."""
    received = datetime.now(UTC)
    result = WebhookResult(detail="")
    timed: list[tuple[int, PushCommit, datetime | None]] = []
    for index, commit in enumerate(push.commits):
        try:
            timed.append((index, commit, commit_time(commit)))
        except ValueError as exc:
            result.refused.append(RefusedCommit(commit=commit.id[:200], reason=str(exc)))
    unrunnable = {c.name: reason for c in components if (reason := cannot_run(c)) is not None}
    for component in sorted(components, key=lambda c: c.id):  # in one order: no deadlock
        if component.name not in unrunnable:
            reports_take_turns(session, component.id)
    for component in components:
        if component.name in unrunnable:  # its jobs could only fail on a host
            continue
        for index, commit, when in timed:
            data = RevisionCreate(
                component=component.name,
                title=commit.id[:TITLE_LENGTH],
                sort_key=sort_key(when or received, index),
                commit=commit.id,
                branch=push.branch or "",
                message=commit.message[:10_000],
                committed_at=when,
            )
            revision = _add_revision(session, component, data)
            if isinstance(revision, str):
                result.refused.append(RefusedCommit(commit=commit.id[:200], reason=revision))
                continue
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
    refused = f", {len(result.refused)} commit(s) refused" if result.refused else ""
    runnable = [c.name for c in components if c.name not in unrunnable]
    result.detail = (
        f"{len(result.created)} revision(s) created, {result.existing} already known"
        f"{refused} for {', '.join(runnable) or 'no component'}"
        + "".join(f"; none for {reason}" for reason in unrunnable.values())
    )
    return result


def _unverified(secrets: set[str], proof: str) -> str:
    """Why a delivery is refused: no secret to check it with, or none it was signed with (the
    same answer whatever the body holds: a trial saw a malformed body told "does not match"
    where a well-formed one was told no secret is configured)."""
    return f"{proof} does not match" if any(secrets) else "no webhook secret is configured"


def _own_secrets(session: Session) -> bool:
    """Whether any component has a webhook secret of its own."""
    own = Component.webhook_secret.is_not(None) & (Component.webhook_secret != "")
    return bool(session.scalar(select(exists().where(own))))


def authenticate_push(
    session: Session, body: bytes, verify: Verifier, default_secret: str
) -> tuple[Push, list[Component]]:
    """The push and the components it is authentically meant for (maybe none).

    Raises Unauthorized when no applicable secret (a matching component's own, else
    ``default_secret``) authenticates the delivery, BadRequest when an authentic body is not a
    push event. Where no component has a secret of its own, the server-wide one is the only one
    that can verify the delivery, and it is checked before the body is read: a forged delivery
    costs an HMAC, not a JSON parse and a query for its repository.
    """
    if not verify(default_secret) and not _own_secrets(session):
        raise Unauthorized(_unverified({default_secret}, verify.proof))
    try:
        push = parse_push(body)
    except BadRequest as unreadable:
        if not verify(default_secret):
            # a component's own secret is found through the repository the push names
            # a probe's body, signed with its component's own secret, was told "no webhook
            # secret is configured": say which secret was the one that could be checked
            said = (
                f"{verify.proof} does not match the server-wide secret"
                if default_secret
                else "no server-wide webhook secret is configured"
            )
            raise Unauthorized(
                f"{said}, and only it can verify this body: it is no push Redline can read "
                f"({unreadable.detail[:200]}), and a component's own secret is found through the "
                "repository a push names"
            ) from None
        raise
    candidates = _of_repository(session, push)
    secrets = {c.webhook_secret or default_secret for c in candidates} or {default_secret}
    if not any(verify(secret) for secret in secrets):
        raise Unauthorized(_unverified(secrets, verify.proof))
    return push, [
        c
        for c in candidates
        if push.branch is not None
        and c.branch == push.branch
        and verify(c.webhook_secret or default_secret)
    ]


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
