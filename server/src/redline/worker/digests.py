"""Digests: a digest subscription's alerts gathered into one message a period (a day), the
first a day after it was made, leaving out the regressions a person has set aside or judging
again has withdrawn since their alert (but for the follow-up that says it was withdrawn,
`redline.worker.follow_ups`). Each alert tells its regression as it is when the digest goes
out (a trial's digest told a regression fixed since its alert as "new")."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime

from redline.server.models import (
    WITHDRAWN,
    Alert,
    Regression,
    RegressionState,
    Subscription,
    utcnow,
)
from redline.worker import messages
from redline.worker.alerts import PERIOD, TELLING, new_delivery
from redline.worker.follow_ups import EVENTS
from redline.worker.told import mark_said
from sqlalchemy import and_, exists, func, or_, select
from sqlalchemy.orm import Session

#: a regression triaged so, or withdrawn, before a digest is sent is left out of it (a trial's
#: digest told a regression marked a false positive hours before as "confirmed")
SETTLED = (RegressionState.false_positive, RegressionState.ignored)


def _told(session: Session, subscription_id: int, waiting: Sequence[Alert]) -> list[Alert]:
    """The waiting alerts a digest tells, their regressions as they are now (and recorded as
    told so, `RegressionTold`): not those of regressions a person has set aside, nor of
    withdrawn ones but for the withdrawal itself, nor a follow-up the regression has settled
    past since (told "not confirmed", then confirmed after all: the digest says the latter)."""
    regressions = {
        regression.id: regression
        for regression in session.scalars(
            select(Regression).where(
                Regression.id.in_({alert.regression_id for alert in waiting}),
            )
        )
    }
    told = []
    for alert in waiting:
        regression = regressions.get(alert.regression_id or 0)
        if regression is not None:
            follow_up = alert.kind not in TELLING
            if regression.state in SETTLED:
                continue
            if follow_up and alert.kind != EVENTS.get(regression.confirmation):
                continue  # settled otherwise since: the follow-up of that is told instead
            if regression.confirmation == WITHDRAWN and not follow_up:
                continue  # only its withdrawal
            alert.body = {**alert.body, "regression": messages.regression_body(regression)}
            mark_said(session, subscription_id, regression.id, regression.confirmation)
        told.append(alert)
    return told


def send_digests(session: Session, now: datetime | None = None) -> list[int]:
    """One message per digest subscription whose period has passed (since its last digest, or
    since it was made: a trial's first "daily" digest went out at the next 15-minute beat) and
    that has alerts not sent yet; and one per subscription switched from digest to immediate
    with alerts still waiting (a review: they were never sent). Returns the new deliveries'
    ids."""
    now = now or utcnow()
    made = []
    waits = exists().where(Alert.subscription_id == Subscription.id, Alert.delivery_id.is_(None))
    due = session.scalars(
        select(Subscription)
        .where(
            or_(
                and_(
                    Subscription.delivery == "digest",
                    func.coalesce(Subscription.digest_sent, Subscription.created) <= now - PERIOD,
                ),
                and_(Subscription.delivery == "immediate", waits),
            )
        )
        .with_for_update(skip_locked=True)
    ).all()
    for subscription in due:
        waiting = session.scalars(
            select(Alert)
            .where(and_(Alert.subscription_id == subscription.id, Alert.delivery_id.is_(None)))
            .order_by(Alert.id)
        ).all()
        told = _told(session, subscription.id, waiting)
        if not told:
            continue  # the settled ones wait: told should a person take them up again
        payload = messages.digest_body([alert.body for alert in told])
        delivery = new_delivery(subscription, "digest", payload, subscription.component_id)
        session.add(delivery)
        session.flush()
        for alert in told:
            alert.delivery_id = delivery.id
        subscription.digest_sent = now
        made.append(delivery.id)
    return made
