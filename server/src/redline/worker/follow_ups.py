"""What a subscriber told of a regression hears when its confirmation settles afterwards.

An eager subscription (``confirmed_only`` false) hears of a regression while it is suspected;
any subscription can hear of one that a re-analysis or a later re-judging withdraws. A trial's
subscriber was told of a suspected +40 % regression and never heard that it was dropped, nor
that another held, with the figures its pairs had measured. So once a subscription has been
sent a regression (an immediate alert, or a digest that carried it), what it was last told of
its confirmation is kept (`RegressionTold`), and a confirmation that differs later makes one
more alert, of the changes the subscription's filters keep (``counters``, ``min_effect``):

- ``regression.confirmed``: it held, by one of those changes (told while suspected);
- ``regression.not_confirmed``: its re-runs or the revisions after it dropped every change;
- ``regression.withdrawn``: judged again, its revisions no longer show any of its changes.

Each carries the regression as it is now (confirmation and its reason) and those changes with
their current figures (the held ones for a confirmation; for a withdrawal, which has none left,
those it was told). A regression a person has triaged as fixed, ignored or a false positive is
theirs: no follow-up then. One whose settling concerns none of the subscription's changes (an
rss change held, for a subscriber of cpu) is recorded as told, with nothing sent.
"""

from __future__ import annotations

from typing import Any

from redline.server.db import session_scope
from redline.server.models import (
    WITHDRAWN,
    Alert,
    Component,
    Regression,
    RegressionTold,
    Subscription,
)
from redline.worker import messages
from redline.worker.alerts import (
    SILENCED,
    TELLING,
    add_alert,
    component_subscriptions,
    flagged_rows,
    scan_component,
    wants,
)
from redline.worker.history import reanalysing
from redline.worker.regression_summary import CONFIRMED, NOT_CONFIRMED
from redline.worker.told import identity, mark_said
from sqlalchemy import func, select, true
from sqlalchemy.orm import Session

#: the event that tells each settled confirmation
EVENTS = {
    CONFIRMED: "regression.confirmed",
    NOT_CONFIRMED: "regression.not_confirmed",
    WITHDRAWN: "regression.withdrawn",
}


def _told_changes(session: Session, subscription_id: int, regression_id: int) -> list[dict]:
    """The changes the subscription was sent of the regression, each once, as told."""
    bodies = session.scalars(
        select(Alert.body)
        .where(
            Alert.subscription_id == subscription_id,
            Alert.regression_id == regression_id,
            Alert.kind.in_(TELLING),
            Alert.delivery_id.is_not(None),
        )
        .order_by(Alert.id)
    )
    told: dict[tuple[Any, ...], dict] = {}
    for body in bodies:  # oldest first: the figures it was last told of each stand
        for change in body.get("changes", []):
            told[(*identity(change), change["revision"]["title"])] = change
    return list(told.values())


def _changes(
    session: Session, component: Component, regression: Regression, subscription: Subscription
) -> list[dict[str, Any]]:
    """The changes a follow-up of the regression tells the subscription, empty when its
    settling concerns none of those its filters keep."""
    if regression.confirmation == WITHDRAWN:
        return _told_changes(session, subscription.id, regression.id)
    own = [
        change
        for change in (
            messages.change_body(component.name, detection, series, revision, baseline_title)
            for detection, series, revision, baseline_title, *_ in flagged_rows(
                session, component, regression.id
            )
        )
        if wants(subscription, True, change)
    ]
    if regression.confirmation == CONFIRMED:
        return [change for change in own if change["confirmation"] == "held"]
    return own  # not confirmed: every change dropped


def _unsaid(session: Session, subscription_id: int, component_id: int) -> list[Regression]:
    """The component's regressions the subscription was sent, not triaged away, whose
    confirmation has settled otherwise than it was last told."""
    return list(
        session.scalars(
            select(Regression)
            .join(RegressionTold, RegressionTold.regression_id == Regression.id)
            .where(
                RegressionTold.subscription_id == subscription_id,
                Regression.component_id == component_id,
                Regression.state.not_in(SILENCED),
                Regression.confirmation.in_(list(EVENTS)),
                RegressionTold.confirmation != Regression.confirmation,
            )
            .order_by(Regression.id)
        )
    )


def tell_settled(session: Session, component_id: int) -> list[int]:
    """Write the follow-ups the component's regressions call for; returns the new deliveries'
    ids (immediate subscriptions; a digest one gathers its follow-ups as its other alerts)."""
    component = session.get_one(Component, component_id)
    made: list[int] = []
    for subscription in component_subscriptions(session, component_id):
        for regression in _unsaid(session, subscription.id, component_id):
            mark_said(session, subscription.id, regression.id, regression.confirmation)
            changes = _changes(session, component, regression, subscription)
            if not changes:
                continue  # none of its own changes settled so: nothing to tell it
            event = EVENTS[regression.confirmation]
            told = add_alert(
                session,
                subscription,
                component.id,
                regression_id=regression.id,
                revision_id=regression.bad_revision_id,
                kind=event,
                body=messages.alert_body(component.name, event, regression, changes),
            )
            made.extend([told.delivery_id] if told.delivery_id is not None else [])
    session.flush()
    return made


def tell_component(session: Session, component_id: int) -> list[int]:
    """Everything the component's changes call for telling (`scan_component`'s alerts, then
    the follow-ups); returns the new deliveries' ids."""
    return scan_component(session, component_id) + tell_settled(session, component_id)


def tell_listened(database_url: str) -> list[int]:
    """`tell_component` for every component someone listens to, each in its own transaction:
    what falls due with time alone, with no detection to scan after (a regression's growth
    held back within its period waited for the component's next commit, days on a quiet one:
    a review). Returns the new deliveries' ids."""
    with session_scope(database_url) as session:
        listening = select(Subscription.component_id).where(Subscription.component_id.is_not(None))
        everyone = session.scalar(
            select(func.count())
            .select_from(Subscription)
            .where(Subscription.component_id.is_(None))
        )
        ids = session.scalars(
            select(Component.id)
            .where(true() if everyone else Component.id.in_(listening))
            .order_by(Component.id)
        ).all()
    made = []
    for component_id in ids:
        with session_scope(database_url) as session:
            if not reanalysing(session, component_id):  # told once it ends, as its scan is
                made += tell_component(session, component_id)
    return made
