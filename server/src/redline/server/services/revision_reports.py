"""CI's report of a revision: a new revision, or the one reported before of the same commit
(one commit under two titles: CI's full SHA and a webhook's 12 digits are one revision)."""

from __future__ import annotations

from collections.abc import Collection, Iterable

from redline.recording.format import COMMIT_HASH
from redline.server.models import Component, Host, Job, JobState, Revision
from redline.server.schemas.revisions import RevisionCreate
from redline.server.services.components import get_component, revision_of_commit, same_commit
from redline.server.services.errors import Conflict, Unprocessable
from redline.server.services.repos import repo_key
from redline.server.services.revisions import (
    CANCELLED,
    create_revision,
    require_own_repository,
)
from sqlalchemy import func, select
from sqlalchemy.orm import Session

#: the first key of the advisory lock that reports of one component's revisions take turns on
REPORT_LOCK = 0x5252  # "RR"


def reports_take_turns(session: Session, component_id: int) -> None:
    """Reports of the component's revisions (CI's, a webhook's push, an import) take turns for
    the rest of the transaction: each looks for the commit, then makes its revision, and two at
    once each found none and made one (a review: CI's full SHA and a webhook's 12 digits, one
    commit under two titles). Nothing else waits for it (a verdict being stored does not)."""
    session.execute(select(func.pg_advisory_xact_lock(REPORT_LOCK, component_id)))


def _reported_before(session: Session, data: RevisionCreate) -> Revision | None:
    """The revision ``data`` reports again: of its title and commit, or of its commit under
    another title (CI's full SHA and a webhook's 12 digits); a Conflict naming both commits when
    its title is another commit's."""
    component = get_component(session, data.component)
    require_own_repository(component, data)
    reports_take_turns(session, component.id)
    titled = session.scalar(
        select(Revision).where(Revision.component_id == component.id, Revision.title == data.title)
    )
    if titled is None:
        return revision_of_commit(session, component, data.commit)
    if same_commit(titled.commit, data.commit):
        return titled
    raise Conflict(
        f"component {data.component!r} already has a revision {data.title!r}, of commit "
        f"{titled.commit!r}; this report says {data.commit!r}"
    )


def require_hash(commit: str) -> None:
    """Unprocessable unless ``commit`` is a commit's hash (a report not an admin's).
    A branch or tag moves: the hosts measure whatever it names when they run it. A fifth
    trial's ci token reported its branch under a new title, placed just before the revision
    that had failed CI on a confirmed regression: the hosts measured that same commit again,
    and the failed revision, judged against it, passed. Named by its hash, a commit reported
    again is the revision reported before, whatever its title (`_reported_before`)."""
    if COMMIT_HASH.fullmatch(commit):
        return
    raise Unprocessable(
        f"commit {commit[:200]!r} is not a commit hash: a report names the commit it measures "
        "by its hash, 7 to 64 hex digits (`redline ci report` sends HEAD's), not a branch or "
        "tag, which moves: the hosts would measure whatever it names when they run it, maybe "
        "a commit reported before under another title. Only an admin token may name a branch "
        "or tag"
    )


def cannot_run(component: Component) -> str | None:
    """Why no performance host could run the component's revisions: no repository or no suite
    file set (a component made for imported results); None when one could."""
    missing = [field for field in ("repo", "suite") if not getattr(component, field)]
    if not missing:
        return None
    return (
        f"component {component.name!r} has no {' and no '.join(missing)} set: no performance "
        f"host could run its revisions; an admin sets {' and '.join(missing)} (PATCH "
        f"/api/v1/components/{component.name}, or its settings page); results can be "
        "imported without (POST /api/v1/import/results or /api/v1/import/lnt)"
    )


def report_revision(
    session: Session, data: RevisionCreate, admin: bool = False
) -> tuple[Revision, bool]:
    """CI's report: the revision made (True), or the one reported before with the same commit
    (False: a re-run pipeline, or CI and a webhook both reporting it, whose sort keys and titles
    may differ in form: the first report's stand); a title taken by another commit is a
    Conflict naming both, and so is a component no host could run (`cannot_run`: a trial's
    revisions were taken, and each job failed on its host)."""
    if not admin:  # only an admin names a commit by a branch or tag (`require_hash`)
        require_hash(data.commit)
    if (reason := cannot_run(get_component(session, data.component))) is not None:
        raise Conflict(reason)
    reported = _reported_before(session, data)
    if reported is not None:
        _queue_cancelled_again(session, reported)
        return reported, False
    try:
        return create_revision(session, data), True
    except Conflict:  # reported meanwhile by another request
        reported = _reported_before(session, data)
        if reported is None:
            raise
        return reported, False


def _queue_cancelled_again(session: Session, revision: Revision) -> None:
    """A revision reported again whose own runs were cancelled (`cancel_revision`: CI cancelled
    a superseded pipeline, then ran it again) has those runs queued anew; runs that finished
    keep their results. A trial's re-report of a cancelled commit answered 200 and queued
    nothing: the revision stayed cancelled, with no way to measure it."""
    cancelled = session.scalars(
        select(Job)
        .where(
            Job.revision_id == revision.id,
            Job.pair == 0,
            Job.remeasures_job_id.is_(None),
            Job.state == JobState.cancelled,
            Job.reason == CANCELLED,
        )
        .with_for_update()
    ).all()
    for job in cancelled:
        job.state, job.reason, job.attempts = JobState.queued, "", 0
        job.lease_expires_at, job.host_id = None, None
    if cancelled:
        session.commit()
        session.refresh(revision)


def remotes_warning(component: Component, remotes: list[str]) -> str:
    """What to tell a report whose work tree's remotes (`RevisionCreate.remotes`) are none of
    them the component's repository: the hosts check the commit out of that one, and a trial
    that reported from the wrong work tree saw its jobs fail minutes later ("CheckoutError").
    Empty when they match, when none were sent, or when the component names no repository."""
    keys = {repo_key(remote) for remote in remotes} - {""}
    # a key stored before `repo_key` dropped the slash a work tree's `.git` folder left
    own = component.repo_key.rstrip("/")
    if not keys or not own or own in keys:
        return ""
    return (
        f"this work tree's remotes ({', '.join(sorted(keys))}) are not the component's "
        f"repository ({own}): the hosts check the commit out of that one, and "
        "fail if it is not there (run in the component's work tree; a mirror of it is fine)"
    )


def unserved_labels(session: Session, needed: Iterable[Collection[str]]) -> tuple[str, ...] | None:
    """The first of the ``needed`` label sets that no registered host has every label of,
    sorted; () when each has such a host; None when no host has registered yet."""
    hosts = [set(labels or []) for labels in session.scalars(select(Host.labels))]
    if not hosts:
        return None
    for labels in needed:
        if not any(set(labels) <= held for held in hosts):
            return tuple(sorted(labels))
    return ()


def labels_warning(session: Session, component: Component) -> str:
    """What to tell a report whose component's jobs need labels no registered host has (a
    trial's `ci report` said nothing of it; only `ci wait`, minutes later, did). Empty when a
    host has them, when they need none, or when no host has registered yet (one may be
    starting)."""
    missing = unserved_labels(session, [component.host_labels or []])
    if not missing:
        return ""
    return (
        f"no registered host has the label(s) {', '.join(map(repr, missing))} "
        f"{component.name}'s jobs need: they wait until one does (give a host `redline agent "
        "--label`, and its token `--labels`, or an admin changes the component's host_labels)"
    )
