"""What a subscription was already told, so that no change is told twice.

A change is first known by its series x revision (`AlertedChange`). A re-analysis can move a
flagged change to another revision, such as a revision reported late between its baseline and
the one it was found at, without it being another change. So a change is also one told before
when the subscription was told a change of the same series, in the same direction, at a range
of revisions that overlaps its own: the told change's (baseline, revision], or the range of the
regression it was told in. A change that moves to a later revision past both ranges is told
again: nothing tells it apart from a new step after a false alarm.
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Collection
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from redline.server.models import (
    WITHDRAWN,
    Alert,
    AlertedChange,
    Regression,
    RegressionTold,
    Revision,
    Series,
    Subscription,
)
from sqlalchemy import ColumnElement, exists, select
from sqlalchemy.dialects.postgresql import insert
from sqlalchemy.orm import Session

#: a range of revisions (good, bad] as their order keys; "" is before every revision
#: (newest baseline revision, revision], each end as (sort key, id): revisions of one sort key
#: keep their reported order, as everywhere (a span by keys alone could be empty)
Place = tuple[str, int]
Span = tuple[Place, Place]


def identity(change: dict[str, Any]) -> tuple[Any, ...]:
    """What names a change's series in an alert's body (`redline.worker.messages.change_body`)."""
    return (
        change["case"],
        change["phase"],
        json.dumps(change["parameters"], sort_keys=True),
        change["process"],
        change["counter"],
    )


def _series_identity(series: Series) -> tuple[Any, ...]:
    params = json.loads(series.params) if series.params.startswith("{") else {}
    return (series.case, series.phase, json.dumps(params, sort_keys=True), series.process,
            series.counter)  # fmt: skip


def overlaps(one: Span, other: Span) -> bool:
    return one[0] < other[1] and other[0] < one[1]


@dataclass(frozen=True)
class Change:
    """One flagged detection as an alert tells it."""

    series_id: int
    revision_id: int
    regression_id: int | None
    worse: bool
    effect: float | None
    confirmation: str
    reported: datetime  # when its revision was reported
    span: Span  # (newest baseline revision, its revision]
    body: dict[str, Any]


@dataclass(frozen=True)
class Told:
    """A change a subscription was told: in which alert, which way, over which ranges."""

    alert_id: int
    regression_id: int | None  # the alert's regression; None once that was deleted
    direction: str
    spans: tuple[Span, ...]

    def covers(self, direction: str, span: Span) -> bool:
        return direction == self.direction and any(overlaps(span, told) for told in self.spans)


def _not_withdrawn() -> ColumnElement[bool]:
    """An alert whose regression was not withdrawn since: a change told in a withdrawn one
    counts as untold, so that finding it again tells it again (a third trial's subscriber heard
    a confirmed +80 % regression withdrawn by a configuration change, and nothing when the
    change was put back and the same regression found again: its last word was "withdrawn")."""
    return ~exists().where(
        Regression.id == Alert.regression_id, Regression.confirmation == WITHDRAWN
    )


def told_pairs(session: Session, subscription_id: int) -> set[tuple[int, int]]:
    """The (series, revision) of every change the subscription was told (`_not_withdrawn`)."""
    return set(
        session.execute(
            select(AlertedChange.series_id, AlertedChange.revision_id)
            .join(Alert, Alert.id == AlertedChange.alert_id)
            .where(AlertedChange.subscription_id == subscription_id, _not_withdrawn())
        )
    )


def told_of(
    session: Session, component_id: int, subscription_id: int, series_ids: Collection[int]
) -> dict[int, list[Told]]:
    """By series, the changes of these series the subscription was told, with their ranges."""
    rows = session.execute(
        select(
            Series,
            Revision.title,
            Revision.order_key,
            Revision.id,
            Alert.id,
            Alert.regression_id,
            Alert.body,
        )
        .select_from(AlertedChange)
        .join(Series, Series.id == AlertedChange.series_id)
        .join(Revision, Revision.id == AlertedChange.revision_id)
        .join(Alert, Alert.id == AlertedChange.alert_id)
        .where(
            AlertedChange.subscription_id == subscription_id,
            AlertedChange.series_id.in_(series_ids),
            _not_withdrawn(),
        )
    ).all()
    found: list[tuple[int, int, int | None, str, Place, list[str]]] = []
    for series, title, order_key, revision_id, alert_id, regression_id, body in rows:
        key = (order_key, revision_id)
        named = _series_identity(series)
        for change in body.get("changes", []):
            if change["revision"]["title"] == title and identity(change) == named:
                regression = body.get("regression") or {}
                bounds = [change.get("baseline") or "", title]
                bounds += [regression.get(end, {}).get("title", "") for end in ("good", "bad")]
                found.append((series.id, alert_id, regression_id, change["direction"], key, bounds))
                break
    titles = {title for *_, bounds in found for title in bounds if title}
    keys: dict[str, Place] = {
        title: (order_key, revision_id)
        for title, order_key, revision_id in session.execute(
            select(Revision.title, Revision.order_key, Revision.id).where(
                Revision.component_id == component_id, Revision.title.in_(titles)
            )
        )
    }
    told: dict[int, list[Told]] = defaultdict(list)
    for series_id, alert_id, regression_id, direction, key, bounds in found:
        baseline, _, good, bad = bounds
        spans = [(keys.get(baseline, ("", 0)), key)]
        if good in keys and bad in keys:
            spans.append((keys[good], keys[bad]))
        told[series_id].append(Told(alert_id, regression_id, direction, tuple(spans)))
    return told


def mark_told(session: Session, subscription: Subscription, change: Change, alert_id: int) -> None:
    """Record the change as told in ``alert_id`` (again, when told in a withdrawn one before)."""
    told = insert(AlertedChange).values(
        subscription_id=subscription.id,
        series_id=change.series_id,
        revision_id=change.revision_id,
        alert_id=alert_id,
    )
    session.execute(
        told.on_conflict_do_update(
            index_elements=[
                AlertedChange.subscription_id,
                AlertedChange.series_id,
                AlertedChange.revision_id,
            ],
            set_={"alert_id": told.excluded.alert_id},
        )
    )


def untold(
    session: Session,
    component_id: int,
    subscription: Subscription,
    candidates: list[Change],
    told_series: set[int],
) -> list[Change]:
    """The candidates the subscription was not told before under another revision (a re-analysis
    moved them within the range they were told with): those are marked told, as the alert that
    told them, and that alert follows their regression if its own was deleted. Only series it
    was told a change of (``told_series``) are looked up."""
    near = {c.series_id for c in candidates} & told_series
    if not near:
        return candidates
    told = told_of(session, component_id, subscription.id, near)
    fresh = []
    for change in candidates:
        direction = change.body["direction"]
        match = next(
            (t for t in told.get(change.series_id, []) if t.covers(direction, change.span)), None
        )
        if match is None:
            fresh.append(change)
            continue
        mark_told(session, subscription, change, match.alert_id)
        if match.regression_id is None and change.regression_id is not None:
            session.get_one(Alert, match.alert_id).regression_id = change.regression_id
    session.flush()
    return fresh


def mark_said(
    session: Session, subscription_id: int, regression_id: int, confirmation: str
) -> None:
    """Record that the subscription was sent the regression as ``confirmation``
    (`RegressionTold`)."""
    said = insert(RegressionTold).values(
        subscription_id=subscription_id, regression_id=regression_id, confirmation=confirmation
    )
    session.execute(
        said.on_conflict_do_update(
            index_elements=[RegressionTold.subscription_id, RegressionTold.regression_id],
            set_={"confirmation": said.excluded.confirmation},
        )
    )
