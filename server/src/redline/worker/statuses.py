"""Commit statuses, one revision's in order: each a `Delivery` keyed ``status:{revision}:...``
(`commit_status`). A revision's state can come back (a late arrival has
it judged again: success, pending, success), so the last one made is the one the commit must
end at: older ones not sent yet are superseded, and one is not sent while an older one of its
revision is (two at once land in either order)."""

from __future__ import annotations

import uuid
from datetime import datetime
from typing import Any

from redline.recording.format import COMMIT_HASH
from redline.server.db import share_component
from redline.server.models import Component, Delivery, Revision
from redline.server.services.ci_verdict import ci_verdict
from sqlalchemy import ColumnElement, and_, func, or_, select, update
from sqlalchemy.orm import Session, aliased


def _same_revision(other: Any) -> ColumnElement[bool]:
    """``other`` is a commit status of the same revision as `Delivery` (keys
    ``status:{revision}:...``, `commit_status`)."""
    return and_(
        Delivery.kind == "status",
        other.kind == "status",
        func.split_part(other.key, ":", 2) == func.split_part(Delivery.key, ":", 2),
    )


def supersede(session: Session, now: datetime) -> None:
    """A commit status not sent yet (or whose lease lapsed) when a newer one of its revision
    exists is superseded, never sent: sent after the newer one, it would leave the commit at the
    older state (a revision judged again after a late arrival goes success, pending, success)."""
    newer = aliased(Delivery)
    session.execute(
        update(Delivery)
        .where(
            or_(
                Delivery.state == "pending",
                and_(Delivery.state == "sending", Delivery.lease_until < now),
            ),
            select(newer.id).where(_same_revision(newer), newer.id > Delivery.id).exists(),
        )
        .values(
            state="superseded",
            lease_until=None,
            last_error="a newer commit status of its revision replaced it",
        )
        .execution_options(synchronize_session=False)
    )


def in_flight_before(now: datetime) -> ColumnElement[bool]:
    """An older commit status of the same revision is being sent: this one waits for it (two
    sent at once may land in either order)."""
    older = aliased(Delivery)
    return (
        select(older.id)
        .where(
            _same_revision(older),
            older.id < Delivery.id,
            older.state == "sending",
            older.lease_until >= now,
        )
        .exists()
    )


def status_key(session: Session, revision_id: int, state: str) -> str | None:
    """The delivery key of the revision's commit status in ``state``, None when the last one
    told already says it. A state comes back when a late arrival has an old revision judged
    again (`redline.worker.onward`: pending meanwhile): once per revision and state would leave
    the commit at pending. The first status of each state is keyed ``status:{id}:{state}``
    (what `redline.worker.sweeps` looks for), a repeat with how many were told before.
    The caller holds the revision's row (`commit_status`), so two never pick the same key."""
    told = (
        session.execute(
            select(Delivery.event)
            .where(Delivery.kind == "status", Delivery.key.startswith(f"status:{revision_id}:"))
            .order_by(Delivery.id.desc())
        )
        .scalars()
        .all()
    )
    if told and told[0] == f"status.{state}":
        return None
    key = f"status:{revision_id}:{state}"
    return key if f"status.{state}" not in told else f"{key}:{len(told)}"


def commit_status(session: Session, revision_id: int) -> list[int]:
    """The revision's verdict as a commit status, when its component has a target and the
    revision a commit: once per change of its state (pending, success, failure, error)."""
    # Statuses of one revision take turns on its row: two scans at once would read the same
    # statuses told, pick the same key, and the one that read the older verdict could land last.
    # The component's key-share lock first, which the delivery's row takes anyway: taken after
    # the revision's, it deadlocked with an import (`db.share_component`).
    component_id = session.scalar(select(Revision.component_id).where(Revision.id == revision_id))
    if component_id is None:
        return []
    share_component(session, component_id)
    revision = session.get(Revision, revision_id, with_for_update=True)
    if revision is None or not COMMIT_HASH.fullmatch(revision.commit):
        return []  # a forge addresses a status by hash: a branch, a tag or a path gets none
    component = session.get_one(Component, revision.component_id)
    if not component.commit_status:
        return []
    verdict = ci_verdict(session, component.name, revision.title)
    if verdict.state == "pending":
        state, said = "pending", f"waiting for {verdict.waiting_for}"
    elif verdict.state == "failed":
        state, said = "error", "its performance jobs failed or were cancelled"
    elif verdict.regressions:
        state, said = "failure", f"{verdict.regressions} change(s) for the worse"
    elif verdict.undecided:  # never a green status for a measurement the host spoiled
        state, said = "error", f"{verdict.undecided} test case(s) undecided (each says why)"
    else:
        state, said = (
            "success",
            "no change for the worse"
            + (f" ({verdict.skipped} test case(s) without enough data)" if verdict.skipped else ""),
        )
    key = status_key(session, revision.id, state)
    if key is None:
        return []
    delivery = Delivery(
        uid=str(uuid.uuid4()),
        key=key,
        component_id=component.id,
        kind="status",
        event=f"status.{state}",
        payload={
            "sha": revision.commit,
            "state": state,
            "description": f"Redline: {said}",
            "context": f"redline/{component.name}",
            "page": verdict.page,
        },
    )
    session.add(delivery)
    session.flush()
    return [delivery.id]
