"""Digests: a digest subscription's alerts gathered into one message a period (a day), the
first a day after it was made, leaving out the regressions a person has set aside or judging
again has withdrawn since their alert."""

from __future__ import annotations

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
from redline.worker.alerts import PERIOD, new_delivery
from sqlalchemy import and_, func, or_, select
from sqlalchemy.orm import Session

#: a regression triaged so, or withdrawn, before a digest is sent is left out of it (a trial's
#: digest told a regression marked a false positive hours before as "confirmed")
SETTLED = (RegressionState.false_positive, RegressionState.ignored)


def _settled(session: Session, regression_ids: set[int]) -> set[int]:
    """Those of the regressions a person has set aside, or judging again has withdrawn."""
    if not regression_ids:
        return set()
    return set(
        session.scalars(
            select(Regression.id).where(
                Regression.id.in_(regression_ids),
                or_(Regression.state.in_(SETTLED), Regression.confirmation == WITHDRAWN),
            )
        )
    )


def send_digests(session: Session, now: datetime | None = None) -> list[int]:
    """One message per digest subscription whose period has passed (since its last digest, or
    since it was made: a trial's first "daily" digest went out at the next 15-minute beat) and
    that has alerts not sent yet; returns the new deliveries' ids."""
    now = now or utcnow()
    made = []
    due = session.scalars(
        select(Subscription)
        .where(
            Subscription.delivery == "digest",
            func.coalesce(Subscription.digest_sent, Subscription.created) <= now - PERIOD,
        )
        .with_for_update(skip_locked=True)
    ).all()
    for subscription in due:
        waiting = session.scalars(
            select(Alert)
            .where(and_(Alert.subscription_id == subscription.id, Alert.delivery_id.is_(None)))
            .order_by(Alert.id)
        ).all()
        settled = _settled(session, {a.regression_id for a in waiting if a.regression_id})
        told = [alert for alert in waiting if alert.regression_id not in settled]
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
