"""What a subscriber told of a regression hears when its confirmation settles afterwards.

An eager subscription (``confirmed_only`` false) hears of a regression while it is suspected;
any subscription can hear of one that a re-analysis or a later re-judging withdraws. A trial's
subscriber was told of a suspected +40 % regression and never heard that it was dropped, nor
that another held, with the figures its pairs had measured. So once a subscription has been
sent an alert of a regression (delivered, or gathered into a digest), a change of the
regression's confirmation from what that subscription was last told makes one more alert:

- ``regression.confirmed``: it held (told while suspected);
- ``regression.not_confirmed``: its re-runs or the revisions after it dropped every change;
- ``regression.withdrawn``: judged again, its revisions no longer show any of its changes.

Each carries the regression as it is now (confirmation and its reason) and its changes with
their current figures, the dropped ones marked so. A regression a person has triaged as fixed,
ignored or a false positive is theirs: no follow-up then.
"""

from __future__ import annotations

from typing import Any

from redline.server.models import WITHDRAWN, Alert, Component, Regression, Subscription
from redline.worker import messages
from redline.worker.alerts import SILENCED, add_alert, flagged_rows, scan_component
from redline.worker.confirmation import CONFIRMED, NOT_CONFIRMED
from sqlalchemy import exists, or_, select
from sqlalchemy.dialects.postgresql import distinct_on
from sqlalchemy.orm import Session, aliased

#: the event that tells each settled confirmation
EVENTS = {
    CONFIRMED: "regression.confirmed",
    NOT_CONFIRMED: "regression.not_confirmed",
    WITHDRAWN: "regression.withdrawn",
}


def _changes(
    session: Session, component: Component, regression: Regression, subscription_id: int
) -> list[dict[str, Any]]:
    """The regression's changes with their figures now, dropped ones included; for a withdrawn
    one, which has none left, the changes the subscriber was told, as told."""
    now = [
        messages.change_body(component.name, detection, series, revision, baseline_title)
        for detection, series, revision, baseline_title, *_ in flagged_rows(
            session, component, regression.id
        )
    ]
    if now:
        return now
    told = session.scalars(
        select(Alert.body)
        .where(Alert.subscription_id == subscription_id, Alert.regression_id == regression.id)
        .order_by(Alert.id)
    )
    return [change for body in told for change in body.get("changes", [])]


def _unsaid(session: Session, subscription_id: int, component_id: int) -> list[Regression]:
    """The component's regressions the subscription was sent, untriaged or open, whose
    confirmation has settled otherwise than its last alert of them said: one query on the last
    alert of each, however many alerts the subscription has had."""
    sent = aliased(Alert)
    last = (
        select(Alert.regression_id, Alert.body["regression"]["confirmation"].as_string())
        .join(Regression, Regression.id == Alert.regression_id)
        .where(
            Alert.subscription_id == subscription_id,
            Regression.component_id == component_id,
            Regression.state.not_in(SILENCED),
            Regression.confirmation.in_(list(EVENTS)),
            # never sent (a digest's, still waiting): nothing to follow up
            exists().where(
                sent.subscription_id == subscription_id,
                sent.regression_id == Alert.regression_id,
                sent.delivery_id.is_not(None),
            ),
        )
        .ext(distinct_on(Alert.regression_id))
        .order_by(Alert.regression_id, Alert.id.desc())
    )
    said = {regression_id: confirmation for regression_id, confirmation in session.execute(last)}
    if not said:
        return []
    regressions = session.scalars(
        select(Regression).where(Regression.id.in_(list(said))).order_by(Regression.id)
    )
    return [r for r in regressions if said[r.id] != r.confirmation]


def tell_settled(session: Session, component_id: int) -> list[int]:
    """Write the follow-ups the component's regressions call for; returns the new deliveries'
    ids (immediate subscriptions; a digest one gathers its follow-ups as its other alerts)."""
    component = session.get_one(Component, component_id)
    subscriptions = session.scalars(
        select(Subscription)
        .where(or_(Subscription.component_id == component_id, Subscription.component_id.is_(None)))
        .order_by(Subscription.id)
        .with_for_update()  # as `scan_component`: two scans never tell the same thing twice
    ).all()
    made: list[int] = []
    for subscription in subscriptions:
        for regression in _unsaid(session, subscription.id, component_id):
            event = EVENTS[regression.confirmation]
            changes = _changes(session, component, regression, subscription.id)
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
