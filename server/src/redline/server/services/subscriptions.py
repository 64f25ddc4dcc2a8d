"""Subscriptions to a component's alerts (or every component's), and their delivery log."""

from __future__ import annotations

from redline.server.models import Component, Delivery, Subscription
from redline.server.schemas.alerts import (
    DeliveryOut,
    SubscriptionCreate,
    SubscriptionOut,
    SubscriptionUpdate,
)
from redline.server.services.components import get_component
from redline.server.services.errors import Conflict, NotFound, Unprocessable
from sqlalchemy import func, select
from sqlalchemy.orm import Session

#: what a subscription left unsaid gets
DEFAULTS = {
    "counters": [],
    "direction": "regression",
    "min_effect": 0.0,
    "confirmed_only": True,
    "delivery": "immediate",
}


def subscription_out(subscription: Subscription, component: str | None) -> SubscriptionOut:
    return SubscriptionOut(
        id=subscription.id,
        component=component,
        kind=subscription.kind,
        address=subscription.address,
        url=subscription.url,
        format=subscription.format,
        has_secret=bool(subscription.secret),
        counters=list(subscription.counters or []),
        direction=subscription.direction,
        min_effect=subscription.min_effect,
        confirmed_only=subscription.confirmed_only,
        delivery=subscription.delivery,
        created=subscription.created,
    )


def _scope(session: Session, component: str | None) -> int | None:
    return None if component is None else get_component(session, component).id


def _check_target(kind: str, address: str, url: str, secret: str, format_: str) -> None:
    """Unprocessable unless the fields a kind takes are given, and no other kind's."""
    if kind == "email":
        if not address:
            raise Unprocessable("address: an email subscription needs one")
        if url or secret or format_ != "redline":
            raise Unprocessable("url, secret, format: an email subscription takes none of them")
    else:
        if not url:
            raise Unprocessable("url: a webhook subscription needs one")
        if address:
            raise Unprocessable("address: a webhook subscription takes none (it has a url)")


def create_subscription(
    session: Session, component: str | None, data: SubscriptionCreate
) -> SubscriptionOut:
    _check_target(data.kind, data.address, data.url, data.secret, data.format)
    fields = data.model_dump()
    for key, default in DEFAULTS.items():
        if fields[key] is None:
            fields[key] = default
    if data.kind == "email":
        fields.update(url="", secret="", format="redline")
    else:
        fields.update(address="")
    scope = _scope(session, component)
    target = Subscription.url == fields["url"]
    if data.kind == "email":
        target = func.lower(Subscription.address) == fields["address"].lower()
    same = session.scalar(
        _query(session, component).where(Subscription.kind == data.kind, target).limit(1)
    )
    if same is not None:  # a trial's second one would have had every alert told twice
        where = f"components/{component}/" if component else ""
        raise Conflict(
            f"{data.kind} to {fields['address'] or fields['url']!r} is subscribed already "
            f"(subscription {same.id}): change what it is told with PATCH "
            f"/api/v1/{where}subscriptions/{same.id}"
        )
    subscription = Subscription(component_id=scope, **fields)
    session.add(subscription)
    session.commit()
    return subscription_out(subscription, component)


def _query(session: Session, component: str | None):
    component_id = _scope(session, component)
    query = select(Subscription)
    if component_id is None:
        return query.where(Subscription.component_id.is_(None))
    return query.where(Subscription.component_id == component_id)


def list_subscriptions(session: Session, component: str | None) -> list[SubscriptionOut]:
    found = session.scalars(_query(session, component).order_by(Subscription.id))
    return [subscription_out(s, component) for s in found]


def get_subscription(session: Session, component: str | None, ident: int) -> Subscription:
    found = session.scalar(_query(session, component).where(Subscription.id == ident))
    if found is None:
        where = f"component {component!r}" if component else "the server"
        raise NotFound(f"{where} has no subscription {ident}")
    return found


def update_subscription(
    session: Session, component: str | None, ident: int, data: SubscriptionUpdate
) -> SubscriptionOut:
    subscription = get_subscription(session, component, ident)
    for field, value in data.model_dump(exclude_unset=True).items():
        if value is not None:
            setattr(subscription, field, value)
    _check_target(
        subscription.kind,
        subscription.address,
        subscription.url,
        subscription.secret,
        subscription.format,
    )
    session.commit()
    return subscription_out(subscription, component)


def delete_subscription(session: Session, component: str | None, ident: int) -> None:
    """Gone with its alerts and its deliveries not yet sent."""
    session.delete(get_subscription(session, component, ident))
    session.commit()


def delivery_out(delivery: Delivery) -> DeliveryOut:
    return DeliveryOut(
        id=delivery.id,
        uid=delivery.uid,
        subscription=delivery.subscription_id,
        kind=delivery.kind,
        event=delivery.event,
        state=delivery.state,
        attempts=delivery.attempts,
        last_error=delivery.last_error,
        next_try=delivery.next_try if delivery.state == "pending" else None,
        created=delivery.created,
        delivered=delivery.delivered,
    )


def list_deliveries(
    session: Session, component: str | None, ident: int | None, limit: int
) -> list[DeliveryOut]:
    """Newest first: a subscription's (``ident``), or the component's (commit statuses too)."""
    query = select(Delivery).order_by(Delivery.id.desc()).limit(limit)
    if ident is not None:
        query = query.where(
            Delivery.subscription_id == get_subscription(session, component, ident).id
        )
    elif component is not None:
        query = query.where(Delivery.component_id == get_component(session, component).id)
    return [delivery_out(d) for d in session.scalars(query)]


def recent_deliveries(
    session: Session, subscriptions: list[SubscriptionOut], per: int = 3
) -> dict[int, list[DeliveryOut]]:
    """Each subscription's newest ``per`` deliveries, newest first (for the settings pages)."""
    newest = (
        func.row_number()
        .over(partition_by=Delivery.subscription_id, order_by=Delivery.id.desc())
        .label("newest")
    )
    ranked = (
        select(Delivery.id, newest)
        .where(Delivery.subscription_id.in_([s.id for s in subscriptions]))
        .subquery()
    )
    found = session.scalars(
        select(Delivery)
        .join(ranked, ranked.c.id == Delivery.id)
        .where(ranked.c.newest <= per)
        .order_by(Delivery.id.desc())
    )
    recent: dict[int, list[DeliveryOut]] = {}
    for delivery in found:
        recent.setdefault(delivery.subscription_id or 0, []).append(delivery_out(delivery))
    return recent


def component_of(session: Session, subscription: Subscription) -> str | None:
    if subscription.component_id is None:
        return None
    return session.get_one(Component, subscription.component_id).name
