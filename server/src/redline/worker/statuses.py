"""Commit statuses, one revision's in order: each a `Delivery` keyed ``status:{revision}:...``
(`redline.worker.alerts.commit_status`). A revision's state can come back (a late arrival has
it judged again: success, pending, success), so the last one made is the one the commit must
end at: older ones not sent yet are superseded, and one is not sent while an older one of its
revision is (two at once land in either order)."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from redline.server.models import Delivery
from sqlalchemy import ColumnElement, and_, func, or_, select, update
from sqlalchemy.orm import Session, aliased


def _same_revision(other: Any) -> ColumnElement[bool]:
    """``other`` is a commit status of the same revision as `Delivery` (keys
    ``status:{revision}:...``, `redline.worker.alerts`)."""
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
