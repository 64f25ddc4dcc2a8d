"""Which commit a revision's runs measure: the one its name named when a host first ran it.

A revision names its commit as it was reported: a ci token's by its hash (`revision_reports`),
an admin's perhaps by a branch or tag, which moves. The agent records the hash it checked out
(``commit_sha`` in the recording's ``redline.run`` metadata); the first run a host uploads pins
it (`Revision.measured_commit`), every later job of the revision (its own executions, the
confirmation pairs that run it again as a candidate or a baseline) is leased that hash, and a run
that measured another commit is refused: a revision is one commit, and a pair judged against a
baseline whose branch had moved on would judge two other commits than it names.
"""

from __future__ import annotations

from collections.abc import Mapping

from redline.recording.format import COMMIT_HASH
from redline.server.models import Revision
from sqlalchemy import select, update
from sqlalchemy.orm import Session


def commit_to_run(revision: Revision) -> str:
    """What a job of ``revision`` checks out: the hash its first run measured, else its name."""
    return revision.measured_commit or revision.commit


def commit_mismatch(run: Mapping[str, str], revision: Revision, job_id: int) -> str:
    """What in a recording's ``redline.run`` metadata (``run``) says it ran another commit than
    job ``job_id`` of ``revision`` was leased, or ''."""
    name, pinned = revision.commit, revision.measured_commit
    commit = run.get("commit", "")
    # a revision may be reported by a short hash; the agent records the commit it was leased:
    # the name, or the hash pinned (a job leased before the pin has the name)
    if name and not (
        commit.startswith(name) or name.startswith(commit or "\0") or (pinned and commit == pinned)
    ):
        return f"redline.run commit is {commit!r} but job {job_id} expects {name!r}"
    measured = run.get("commit_sha", "")
    if not measured:
        return ""  # an agent older than the field records no hash
    if not COMMIT_HASH.fullmatch(measured):
        return f"redline.run commit_sha {measured[:80]!r} is not a commit hash"
    if COMMIT_HASH.fullmatch(name) and not measured.lower().startswith(name.lower()):
        return f"redline.run commit_sha is {measured!r} but revision {revision.title} is {name!r}"
    if pinned and measured.lower() != pinned:
        return _moved(revision, measured)
    return ""


def pin_measured(session: Session, revision: Revision, run: Mapping[str, str]) -> str:
    """Pin the hash the run measured as its revision's, where none is yet: '' when the run
    measured the revision's pinned commit (or recorded none), else why it is refused (a run
    uploaded at the same time pinned another: the branch moved between the two)."""
    measured = run.get("commit_sha", "").lower()
    if not measured or revision.measured_commit:
        return ""  # none recorded, or pinned already (`commit_mismatch` compared it)
    session.execute(
        update(Revision)
        .where(Revision.id == revision.id, Revision.measured_commit == "")
        .values(measured_commit=measured)
    )  # another upload's pin, committed meanwhile, leaves this one's row as it is
    pinned = session.scalar(select(Revision.measured_commit).where(Revision.id == revision.id))
    return "" if pinned == measured else _moved(revision, measured, pinned)


def _moved(revision: Revision, measured: str, pinned: str | None = None) -> str:
    pinned = pinned or revision.measured_commit
    return (
        f"this run measured commit {measured[:12]}, but revision {revision.title}'s runs measured "
        f"{pinned[:12]} ({revision.commit!r} named another commit when they ran): a revision is "
        "one commit"
    )
