"""Deciding who hears about what: a component's regressions and improvements matched against the
subscriptions, each change told once per subscription.

A scan runs after every detection and re-analysis (`redline.worker.tasks`). For each
subscription it takes the changes its filters keep, drops those it was already told about
(`AlertedChange`: series x revision, so re-analyses, regrouping and confirmation never tell
twice; and a change a re-analysis moved within the range it was told with, `redline.worker.told`),
and writes an `Alert` for each regression with new changes: "regression" the first
time, "regression.updated" when it grew, at most once per digest period. Immediate
subscriptions get a `Delivery` per alert; digest ones collect their alerts until
`redline.worker.digests.send_digests`. Only revisions reported after the subscription was made
are alerted (a new subscription does not replay the history), and a triaged regression (fixed,
ignored, false positive) is never alerted again.

A fault `redline watch` reports at run time (`runtime_alerts`) goes to the subscriptions that
want regressions of its target (``counters`` empty or naming it), once each, its end too.
"""

from __future__ import annotations

import uuid
from collections import defaultdict
from datetime import datetime, timedelta
from typing import Any

from redline.detect.confirmation import DROPPED
from redline.detect.count_rate import METHOD as COUNT_RATE
from redline.detect.counters import worse
from redline.server.models import (
    UNENDED,
    Alert,
    Component,
    Delivery,
    Detection,
    Execution,
    Job,
    JobState,
    Regression,
    RegressionState,
    Revision,
    RuntimeAlarm,
    Series,
    Subscription,
    utcnow,
)
from redline.server.services.detection_config import component_config
from redline.worker import messages
from redline.worker.told import Change, mark_said, mark_told, told_pairs, untold
from sqlalchemy import and_, or_, select
from sqlalchemy.orm import Session, aliased

#: a regression that grows is told again at most this often (and a digest goes out this often)
PERIOD = timedelta(days=1)
#: triage that ends a regression's alerts: someone has looked and decided
SILENCED = (RegressionState.fixed, RegressionState.ignored, RegressionState.false_positive)


def _imported(session: Session, revision_ids: set[int]) -> set[int]:
    """The revisions whose results were imported: no agent can re-run them, so their
    regressions alert when flagged."""
    rows = session.execute(
        select(Execution.revision_id, Execution.meta).where(Execution.revision_id.in_(revision_ids))
    )
    return {revision for revision, meta in rows if (meta or {}).get("imported")}


def _measuring(session: Session, revision_ids: set[int]) -> set[int]:
    """The revisions with own jobs still to run or to ingest, or ingested since the revision
    was last judged (ingestion clears `Revision.analyzed_at`, and a detection sets it only
    where it judged every run: `redline.server.services.analysed`): their changes are told
    once every execution is in and judged (a trial's regression was told with 6 series, and
    grew to 7 when the revision's third execution came 12 s later, the 7th left to a daily
    update; a third trial's alert said +85.6 %, the median of two of three executions, where
    the verdict of all three said +80.4 %: the scan ran between the third's ingestion and its
    judging). No clock is compared: a run ingested just after a detection began, which it
    read, was "updated after analyzed_at", and held its alerts back until the next judging."""
    unjudged = and_(Job.state == JobState.done, Revision.analyzed_at.is_(None))
    return set(
        session.scalars(
            select(Job.revision_id)
            .join(Revision, Revision.id == Job.revision_id)
            .where(
                Job.revision_id.in_(revision_ids),
                Job.pair == 0,
                or_(Job.state.in_(UNENDED), unjudged),
            )
        )
    )


def flagged_rows(
    session: Session,
    component: Component,
    regression_id: int | None = None,
    since: datetime | None = None,
) -> list[Any]:
    """(detection, series, revision, baseline title, baseline sort key, baseline id) of the
    component's flagged detections of its alarm methods, oldest first: of one regression, or of
    the revisions reported since ``since`` outside silenced regressions."""
    alarming = component_config(session, component.id).alarming
    baseline = aliased(Revision)
    query = (
        select(Detection, Series, Revision, baseline.title, baseline.order_key, baseline.id)
        .join(Series, Series.id == Detection.series_id)
        .join(Revision, Revision.id == Detection.revision_id)
        .outerjoin(baseline, baseline.id == Detection.baseline_revision_id)
        .outerjoin(Regression, Regression.id == Detection.regression_id)
        .where(Series.component_id == component.id, Detection.flagged)
        .where(Detection.method.in_(alarming))
        .order_by(Detection.id)
    )
    if regression_id is not None:
        query = query.where(Detection.regression_id == regression_id)
    if since is not None:
        query = query.where(
            Revision.created >= since,
            or_(Regression.id.is_(None), Regression.state.not_in(SILENCED)),
        )
    return list(session.execute(query).all())


def flagged_changes(session: Session, component: Component, since: datetime) -> list[Change]:
    """The component's flagged changes of the alarm methods, on revisions reported since
    ``since``, not dropped by confirmation, outside silenced regressions."""
    rows = flagged_rows(session, component, since=since)
    changes = []
    for detection, series, revision, baseline_title, baseline_key, baseline_id in rows:
        is_worse = detection.direction == worse(series.process, series.counter)
        if is_worse and detection.regression_id is None:
            continue  # not grouped (no span): nothing to point at yet
        if detection.confirmation == DROPPED:
            continue
        body = messages.change_body(component.name, detection, series, revision, baseline_title)
        changes.append(
            Change(
                series.id,
                revision.id,
                detection.regression_id if is_worse else None,
                is_worse,
                detection.effect,
                detection.confirmation,
                revision.created,
                ((baseline_key or "", baseline_id or 0), revision.place),
                body,
            )
        )
    return changes


def wanted(subscription: Subscription, change: Change) -> bool:
    """Whether the subscription's filters keep the change (confirmation aside)."""
    return wants(subscription, change.worse, change.body)


def wants(subscription: Subscription, worse: bool, change: dict[str, Any]) -> bool:
    """Whether the subscription's filters keep a change for the worse (or the better) as an
    alert tells it (`redline.worker.messages.change_body`)."""
    if subscription.direction == "regression" and not worse:
        return False
    if subscription.direction == "improvement" and worse:
        return False
    if subscription.counters and not told_of(change["counter"], subscription.counters):
        return False
    effect = change.get("effect")
    if effect is None or change.get("method") == COUNT_RATE:
        # not a relative change: one from a zero baseline (no ratio; an idle phase's CPU from 0
        # to 8 %), or a count's rate moving by percentage points (timeouts from 0 to 0.6 % of
        # queries is 0.006): `min_effect` dropped both (a review)
        return True
    return abs(effect) >= subscription.min_effect


def told_of(counter: str, counters: list[str]) -> bool:
    """Whether a subscription to ``counters`` hears of ``counter``: by its name, or a driver
    metric's by the metric alone ("rtt_p90_us" hears of "FixedRate/Query(svc/get):rtt_p90_us",
    whatever the action's path)."""
    return counter in counters or counter.rpartition(":")[2] in counters


#: the alerts that tell a regression's changes (a follow-up tells how it settled: `follow_ups`)
TELLING = ("regression", "regression.updated")


def _last_alert(session: Session, subscription_id: int, regression_id: int) -> Alert | None:
    """The subscription's last alert of the regression's changes: its growth is told at most a
    `PERIOD` after it (a follow-up in between holds nothing back)."""
    return session.scalar(
        select(Alert)
        .where(
            Alert.subscription_id == subscription_id,
            Alert.regression_id == regression_id,
            Alert.kind.in_(TELLING),
        )
        .order_by(Alert.id.desc())
        .limit(1)
    )


def new_delivery(
    subscription: Subscription, event: str, payload: dict[str, Any], component_id: int | None
) -> Delivery:
    return Delivery(
        uid=str(uuid.uuid4()),
        subscription_id=subscription.id,
        component_id=component_id,
        kind=subscription.kind,
        event=event,
        payload=payload,
    )


def add_alert(
    session: Session, subscription: Subscription, component_id: int, **fields: Any
) -> Alert:
    """An alert of these ``fields`` (`Alert`'s) stored for ``subscription``, with its delivery
    when the subscription is told at once (a digest one gathers it later)."""
    alert = Alert(subscription_id=subscription.id, **fields)
    session.add(alert)
    session.flush()
    if subscription.delivery == "immediate":
        delivery = new_delivery(subscription, alert.kind, alert.body, component_id)
        session.add(delivery)
        session.flush()
        alert.delivery_id = delivery.id
    return alert


def _alert(
    session: Session,
    subscription: Subscription,
    component: Component,
    kind: str,
    regression: Regression | None,
    changes: list[Change],
) -> Alert:
    body = messages.alert_body(component.name, kind, regression, [c.body for c in changes])
    alert = add_alert(
        session,
        subscription,
        component.id,
        regression_id=regression.id if regression else None,
        revision_id=changes[0].revision_id,
        kind=kind,
        body=body,
    )
    for change in changes:
        mark_told(session, subscription, change, alert.id)
    if regression is not None and alert.delivery_id is not None:  # sent: a digest's, once sent
        mark_said(session, subscription.id, regression.id, regression.confirmation)
    return alert


def component_subscriptions(session: Session, component_id: int) -> list[Subscription]:
    """The subscriptions of the component and of every component, locked: two scans of one
    component never tell the same thing twice."""
    return list(
        session.scalars(
            select(Subscription)
            .where(
                or_(Subscription.component_id == component_id, Subscription.component_id.is_(None))
            )
            .order_by(Subscription.id)
            .with_for_update()
        )
    )


def scan_component(session: Session, component_id: int) -> list[int]:
    """Write the alerts the component's changes call for; returns the new deliveries' ids."""
    component = session.get_one(Component, component_id)
    subscriptions = component_subscriptions(session, component_id)
    if not subscriptions:
        return []
    changes = flagged_changes(session, component, min(s.created for s in subscriptions))
    regressions = {
        r.id: r
        for r in session.scalars(
            select(Regression).where(
                Regression.id.in_({c.regression_id for c in changes if c.regression_id})
            )
        )
    }
    imported = _imported(session, {c.revision_id for c in changes})
    measuring = _measuring(session, {c.revision_id for c in changes})
    # a regression, or an improvement, is told once every execution of its revisions is in
    # (an improvement's revision alone: its None among these held back every improvement)
    waiting = {
        c.regression_id
        for c in changes
        if c.revision_id in measuring and c.regression_id is not None
    }
    changes = [
        c for c in changes if c.revision_id not in measuring and c.regression_id not in waiting
    ]
    made: list[Alert] = []
    now = utcnow()
    for subscription in subscriptions:
        told = told_pairs(session, subscription.id)
        candidates = [
            c
            for c in changes
            if (c.series_id, c.revision_id) not in told
            and wanted(subscription, c)
            and c.reported >= subscription.created
        ]
        fresh = untold(
            session, component_id, subscription, candidates, {series for series, _ in told}
        )
        by_regression: dict[int, list[Change]] = defaultdict(list)
        by_revision: dict[int, list[Change]] = defaultdict(list)
        for change in fresh:
            if change.regression_id is not None:
                by_regression[change.regression_id].append(change)
            else:
                by_revision[change.revision_id].append(change)
        for regression_id, found in by_regression.items():
            regression = regressions[regression_id]
            settled = regression.confirmation == "confirmed" or any(
                c.revision_id in imported for c in found
            )
            if subscription.confirmed_only and not settled:
                continue  # told once confirmed
            last = _last_alert(session, subscription.id, regression_id)
            if last is not None and now - last.created < PERIOD:
                continue  # grew again within the period: told at the next one
            kind = "regression" if last is None else "regression.updated"
            made.append(_alert(session, subscription, component, kind, regression, found))
        for found in by_revision.values():
            made.append(_alert(session, subscription, component, "improvement", None, found))
    session.flush()
    return [alert.delivery_id for alert in made if alert.delivery_id is not None]


def runtime_listeners(component_id: Any, at: Any) -> tuple[Any, ...]:
    """The conditions on `Subscription` that make it hear of a run-time alarm of the component
    at that time (values, or columns of a query over `RuntimeAlarm`): of the component or of
    all, not for improvements only, and made by then."""
    return (
        or_(Subscription.component_id == component_id, Subscription.component_id.is_(None)),
        Subscription.direction != "improvement",
        Subscription.created <= at,
    )


def runtime_alerts(session: Session, alarm_id: int) -> list[int]:
    """Tell the subscriptions of a run-time alarm's component about it, once each (a retried
    task finds the alerts it made); returns the new deliveries' ids."""
    alarm = session.get(RuntimeAlarm, alarm_id)
    if alarm is None:
        return []  # its component was deleted
    component = session.get_one(Component, alarm.component_id)
    told = set(
        session.scalars(select(Alert.subscription_id).where(Alert.runtime_alarm_id == alarm.id))
    )
    body = messages.runtime_body(component.name, alarm)
    made = []
    for subscription in session.scalars(
        select(Subscription)
        .where(*runtime_listeners(component.id, alarm.at))
        .order_by(Subscription.id)
    ):
        if subscription.id in told or (
            subscription.counters and alarm.target not in subscription.counters
        ):
            continue
        alert = add_alert(
            session, subscription, component.id, runtime_alarm_id=alarm.id, kind=body["kind"],
            body=body,
        )  # fmt: skip
        made.extend([alert.delivery_id] if alert.delivery_id is not None else [])
    session.flush()
    return made
