"""The outbox's postman: every due delivery leased, sent (webhook, mail or commit status) and its
outcome stored, each in its own transaction.

A delivery is leased before it is sent (state ``sending`` until ``lease_until``), so a worker
killed mid-send leaves it to be sent again once the lease lapses, with the same delivery id (header
``X-Redline-Delivery``, the mail's Message-ID) for the receiver to recognise. A failure is retried
with exponential backoff and jitter until ``REDLINE_ALERT_MAX_ATTEMPTS``; a mail server's permanent
refusal of the mail (a 5xx reply to its sender, recipient or content) is failed at once, as is a
URL whose host is a link-local or metadata address (`redline.server.core.targets`), which is never
asked. A success is stored as soon as its send returns, even one whose lease lapsed meanwhile, and
is never sent again. Sends run on a few threads with a timeout each (``REDLINE_ALERT_TIMEOUT_S``),
each outcome stored as it comes and free threads given more work meanwhile, so one slow receiver
holds up neither the others nor ingestion and detection, which run in other workers' queues;
a send under way has its lease renewed, so no other run sends it meanwhile. How each kind is
sent: `redline.worker.sending`.
"""

from __future__ import annotations

import logging
import random
import time
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import httpx
from redline.server.core.config import Settings
from redline.server.db import session_scope
from redline.server.models import Component, Delivery, Subscription, utcnow
from redline.worker.sending import SendError, http_client, send
from redline.worker.statuses import in_flight_before, supersede
from sqlalchemy import and_, or_, select, tuple_, update

log = logging.getLogger(__name__)
#: the longest wait between two tries of one delivery
MAX_BACKOFF = timedelta(hours=6)
#: how often a run with sends in flight looks for deliveries that fell due meanwhile (seconds)
POLL_S = 1.0


def backoff(attempts: int, base: float) -> timedelta:
    """The wait after the ``attempts``-th failed try: base x 2^(attempts-1), x 0.5..1.5, at
    most `MAX_BACKOFF` (the jitter applies at the cap too, so retries stay spread out)."""
    ceiling = MAX_BACKOFF.total_seconds() / 1.5
    seconds = min(base * 2.0 ** min(max(attempts - 1, 0), 64), ceiling)
    return timedelta(seconds=seconds * random.uniform(0.5, 1.5))


@dataclass
class Leased:
    """A leased delivery with what sending it needs, detached from its session."""

    delivery: Delivery
    subscription: Subscription | None
    component: Component | None


def claim(database_url: str, limit: int, lease: timedelta, max_attempts: int = 10) -> list[Leased]:
    """Lease up to ``limit`` due deliveries (pending and due, or sending with a lapsed lease),
    each with its subscription and component, in one transaction. One whose lease lapsed
    after its last try (``max_attempts``) is failed, not tried again: its worker stopped
    mid-send that often."""
    now = utcnow()
    with session_scope(database_url) as session:
        supersede(session, now)
        lapsed = session.scalars(
            update(Delivery)
            .where(
                Delivery.state == "sending",
                Delivery.lease_until < now,
                Delivery.attempts >= max_attempts,
            )
            .values(
                state="failed",
                lease_until=None,
                last_error=f"its lease lapsed on its last try ({max_attempts}): the worker "
                "stopped mid-send",
            )
            .returning(Delivery.uid)
        ).all()
        for uid in lapsed:
            log.error("delivery %s failed for good: its lease lapsed on its last try", uid)
        ids = session.scalars(
            select(Delivery.id)
            .where(
                or_(
                    and_(Delivery.state == "pending", Delivery.next_try <= now),
                    and_(Delivery.state == "sending", Delivery.lease_until < now),
                ),
                ~in_flight_before(now),
            )
            .order_by(Delivery.next_try)
            .limit(limit)
            .with_for_update(skip_locked=True)
        ).all()
        if not ids:
            return []
        session.execute(
            update(Delivery)
            .where(Delivery.id.in_(ids))
            .values(state="sending", lease_until=now + lease, attempts=Delivery.attempts + 1)
            .execution_options(synchronize_session=False)
        )
        rows = session.execute(
            select(Delivery, Subscription, Component)
            .outerjoin(Subscription, Subscription.id == Delivery.subscription_id)
            .outerjoin(Component, Component.id == Delivery.component_id)
            .where(Delivery.id.in_(ids))
            .execution_options(populate_existing=True)
        ).all()
        session.expunge_all()
    return [Leased(*row) for row in rows]


def attempt(client: httpx.Client, settings: Settings, leased: Leased) -> SendError | None:
    """One try of one delivery: None when it was taken, else why not."""
    try:
        send(client, leased.delivery, settings, leased.subscription, leased.component)
    except SendError as failure:
        return failure
    except Exception as failure:  # a bug in a renderer must not stop the other deliveries
        log.exception("delivery %s", leased.delivery.uid)
        return SendError(f"{type(failure).__name__}: {failure}")
    return None


def record(
    database_url: str, settings: Settings, outcomes: list[tuple[Leased, SendError | None]]
) -> None:
    """Store tries' outcomes in one transaction: delivered, or pending again after a backoff,
    or failed for good.

    A success is stored whenever it comes: a late one (the lease lapsed, another worker may be
    sending it again, with the same id) is still a success, and nothing sends it after. A
    failure is left to whoever leased the delivery since (its ``attempts`` moved on), and a
    delivered one stays delivered."""
    now = utcnow()
    ours = {leased.delivery.id: (leased.delivery.attempts, error) for leased, error in outcomes}
    with session_scope(database_url) as session:
        found = session.scalars(
            select(Delivery).where(Delivery.id.in_(list(ours))).with_for_update()
        )
        for delivery in found:
            attempt, error = ours[delivery.id]
            if delivery.state == "delivered":
                continue
            if error is None:
                if delivery.attempts != attempt:
                    log.warning(
                        "delivery %s sent after its lease lapsed; try %d may send it again "
                        "(the same id: the receiver can tell)",
                        delivery.uid,
                        delivery.attempts,
                    )
                delivery.state, delivery.delivered, delivery.last_error = "delivered", now, ""
                delivery.lease_until = None
                log.info("delivery %s (%s %s) sent", delivery.uid, delivery.kind, delivery.event)
                continue
            if delivery.attempts != attempt or delivery.state != "sending":
                continue  # leased again since: the later try decides
            delivery.lease_until = None
            delivery.last_error = str(error)
            if error.permanent or delivery.attempts >= settings.alert_max_attempts:
                delivery.state = "failed"
                log.error(
                    "delivery %s failed for good after %d tries: %s",
                    delivery.uid,
                    delivery.attempts,
                    error,
                )
            else:
                delivery.state = "pending"
                delivery.next_try = now + backoff(delivery.attempts, settings.alert_retry_s)
                log.warning(
                    "delivery %s try %d failed (%s); next at %s",
                    delivery.uid,
                    delivery.attempts,
                    error,
                    delivery.next_try.isoformat(),
                )


def renew(database_url: str, leased: list[Leased], lease: timedelta) -> None:
    """Extend the leases of tries still under way, so that no other run sends them too: a
    receiver that answered slower than the lease had one delivery sent again on thread after
    thread until all were held (a review)."""
    ours = [(one.delivery.id, one.delivery.attempts) for one in leased]
    with session_scope(database_url) as session:
        session.execute(
            update(Delivery)
            .where(Delivery.state == "sending", tuple_(Delivery.id, Delivery.attempts).in_(ours))
            .values(lease_until=utcnow() + lease)
            .execution_options(synchronize_session=False)
        )


def deliver_due(
    database_url: str, settings: Settings, threads: int = 8, lease: timedelta | None = None
) -> dict[str, Any]:
    """Send what is due now until nothing is, on ``threads`` threads: leased a few at a time
    (at most one more than each thread sends), each outcome stored as soon as its send ends,
    and what falls due meanwhile taken on while slow sends run; the leases of sends under way
    renewed while they last. Returns counts and the next due time."""
    lease = lease or timedelta(seconds=settings.alert_timeout_s * 3 + 30)
    room = threads * 2
    sent = failed = 0
    in_flight: dict[Future[SendError | None], Leased] = {}
    renewed = time.monotonic()
    with http_client(threads) as client, ThreadPoolExecutor(threads) as pool:
        while True:
            if len(in_flight) <= threads:
                most = room - len(in_flight)
                for leased in claim(database_url, most, lease, settings.alert_max_attempts):
                    in_flight[pool.submit(attempt, client, settings, leased)] = leased
            if not in_flight:
                break
            if time.monotonic() - renewed > lease.total_seconds() / 3:
                renew(database_url, list(in_flight.values()), lease)
                renewed = time.monotonic()
            look = min(POLL_S, lease.total_seconds() / 3)  # renewed well within the lease
            done, _ = wait(in_flight, timeout=look, return_when=FIRST_COMPLETED)
            if not done:
                continue  # slow sends: look for deliveries that fell due meanwhile
            outcomes = [(in_flight.pop(future), future.result()) for future in done]
            record(database_url, settings, outcomes)
            failed += sum(1 for _, error in outcomes if error is not None)
            sent += sum(1 for _, error in outcomes if error is None)
    return {"sent": sent, "failed": failed, "next": next_due(database_url)}


def next_due(database_url: str) -> datetime | None:
    with session_scope(database_url) as session:
        return session.scalar(
            select(Delivery.next_try)
            .where(Delivery.state.in_(("pending", "sending")))
            .order_by(Delivery.next_try)
            .limit(1)
        )
