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
holds up neither the others nor ingestion and detection, which run in other workers' queues.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import random
import smtplib
import socket
import ssl
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from datetime import datetime, timedelta
from email.message import EmailMessage
from email.utils import formatdate
from typing import Any
from urllib.parse import quote, urlsplit

import httpx
from redline.server.core.config import Settings
from redline.server.core.targets import refused_host
from redline.server.db import session_scope
from redline.server.models import Component, Delivery, Subscription, utcnow
from redline.server.schemas.fields import COMMIT_HASH
from redline.worker import messages
from redline.worker.statuses import in_flight_before, supersede
from sqlalchemy import and_, or_, select, update

log = logging.getLogger(__name__)
#: the longest wait between two tries of one delivery
MAX_BACKOFF = timedelta(hours=6)
#: how often a run with sends in flight looks for deliveries that fell due meanwhile (seconds)
POLL_S = 1.0
SIGNATURE_HEADER = "X-Redline-Signature-256"
DELIVERY_HEADER = "X-Redline-Delivery"
EVENT_HEADER = "X-Redline-Event"


class SendError(Exception):
    """A try that failed; the message says why (status and the start of the answer).
    ``permanent``: trying again cannot help (a mail server refused the mail with a 5xx)."""

    def __init__(self, message: str, permanent: bool = False) -> None:
        super().__init__(message)
        self.permanent = permanent


def sign(secret: str, body: bytes) -> str:
    return "sha256=" + hmac.new(secret.encode(), body, hashlib.sha256).hexdigest()


def backoff(attempts: int, base: float) -> timedelta:
    """The wait after the ``attempts``-th failed try: base x 2^(attempts-1), x 0.5..1.5, at
    most `MAX_BACKOFF` (the jitter applies at the cap too, so retries stay spread out)."""
    ceiling = MAX_BACKOFF.total_seconds() / 1.5
    seconds = min(base * 2.0 ** min(max(attempts - 1, 0), 64), ceiling)
    return timedelta(seconds=seconds * random.uniform(0.5, 1.5))


def _post(
    client: httpx.Client, url: str, body: bytes, headers: dict[str, str], timeout: float
) -> None:
    refused = refused_host(urlsplit(url).hostname or "")
    if refused is not None:  # its answer would land in the delivery log: never asked
        raise SendError(f"refused: {refused}", permanent=True)
    try:
        answer = client.post(url, content=body, headers=headers, timeout=timeout)
    except httpx.InvalidURL as error:  # stored before such URLs were refused: no retry mends it
        raise SendError(f"invalid URL: {error}", permanent=True) from None
    except httpx.HTTPError as error:
        raise SendError(f"{type(error).__name__}: {error}") from None
    if not answer.is_success:
        raise SendError(f"HTTP {answer.status_code}: {answer.text[:200]}")


def _webhook(
    client: httpx.Client, delivery: Delivery, subscription: Subscription, settings: Settings
) -> None:
    if subscription.format == "slack":
        data = messages.slack_json(delivery.event, delivery.payload, settings.public_url)
    else:
        data = messages.webhook_json(
            delivery.event, delivery.uid, delivery.payload, settings.public_url, delivery.created
        )
    body = json.dumps(data, separators=(",", ":")).encode()
    headers = {
        "Content-Type": "application/json",
        "User-Agent": "Redline-Hookshot",
        DELIVERY_HEADER: delivery.uid,
        EVENT_HEADER: delivery.event,
    }
    if subscription.secret:
        headers[SIGNATURE_HEADER] = sign(subscription.secret, body)
    _post(client, subscription.url, body, headers, settings.alert_timeout_s)


def _mail(delivery: Delivery, subscription: Subscription, settings: Settings) -> None:
    if not settings.smtp_host:
        raise SendError("no SMTP server: REDLINE_SMTP_HOST is not set")
    subject, text, body = messages.email(delivery.event, delivery.payload, settings.public_url)
    mail = EmailMessage()
    mail["Subject"] = subject
    mail["From"] = settings.smtp_from
    mail["To"] = subscription.address
    mail["Date"] = formatdate(localtime=False)
    mail["Message-ID"] = f"<{delivery.uid}@redline>"
    mail[DELIVERY_HEADER] = delivery.uid
    mail.set_content(text)
    mail.add_alternative(body, subtype="html")
    context = ssl.create_default_context(
        cafile=str(settings.smtp_ca_file) if settings.smtp_ca_file else None
    )
    timeout = settings.alert_timeout_s
    try:
        if settings.smtp_tls == "tls":
            client: smtplib.SMTP = smtplib.SMTP_SSL(
                settings.smtp_host, settings.smtp_port, timeout=timeout, context=context
            )
        else:
            client = smtplib.SMTP(settings.smtp_host, settings.smtp_port, timeout=timeout)
        with client:
            if settings.smtp_tls == "starttls":
                client.starttls(context=context)
            if settings.smtp_user:
                client.login(settings.smtp_user, settings.smtp_password.get_secret_value())
            client.send_message(mail)
    except (OSError, smtplib.SMTPException) as error:
        raise smtp_failure(error) from None


def _said(reply: bytes | str) -> str:
    return (reply.decode(errors="replace") if isinstance(reply, bytes) else reply).strip()


def smtp_failure(error: Exception) -> SendError:
    """A failed SMTP conversation as a `SendError` quoting the server's reply. A 5xx reply to
    the mail itself (its sender, recipient or content) is permanent: the server refuses this
    mail, and would refuse it again. Any other failure (down, slow, a 4xx, the greeting, TLS or
    the login refused) is retried: an outage passes, and an operator can fix a setting."""
    if isinstance(error, smtplib.SMTPRecipientsRefused):
        replies = error.recipients.values()
        said = "; ".join(
            f"{address}: {code} {_said(text)}" for address, (code, text) in error.recipients.items()
        )
        permanent = bool(replies) and all(code >= 500 for code, _ in replies)
        return SendError(f"SMTP: recipient refused: {said}", permanent=permanent)
    if isinstance(error, smtplib.SMTPSenderRefused | smtplib.SMTPDataError):
        what = "sender refused" if isinstance(error, smtplib.SMTPSenderRefused) else "mail refused"
        return SendError(
            f"SMTP: {what}: {error.smtp_code} {_said(error.smtp_error)}",
            permanent=error.smtp_code >= 500,
        )
    if isinstance(error, smtplib.SMTPResponseException):
        said = f"{error.smtp_code} {_said(error.smtp_error)}"
        return SendError(f"SMTP: {type(error).__name__}: {said}")
    return SendError(f"SMTP: {type(error).__name__}: {error}")


def _status(
    client: httpx.Client, delivery: Delivery, component: Component, settings: Settings
) -> None:
    target = component.commit_status or {}
    call = delivery.payload
    sha = str(call["sha"])
    if not COMMIT_HASH.fullmatch(sha):  # one queued before only hashes were: never a path
        raise SendError(f"commit {sha[:80]!r} is not a commit hash: no status is sent", True)
    token, api = target.get("token", ""), str(target.get("api_url", "")).rstrip("/")
    link = settings.public_url.rstrip("/") + call["page"]
    if target.get("provider") == "github":
        url = f"{api}/repos/{target['repository']}/statuses/{sha}"
        data = {
            "state": call["state"],
            "target_url": link,
            "description": call["description"][:140],
            "context": call["context"],
        }
        headers = {
            "Authorization": f"Bearer {token}",
            "Accept": "application/vnd.github+json",
            "X-GitHub-Api-Version": "2022-11-28",
        }
    elif target.get("provider") == "gitlab":
        project = quote(str(target["repository"]), safe="")  # a path: robots%2Fbuilder
        url = f"{api}/projects/{project}/statuses/{sha}"
        state = {"failure": "failed", "error": "failed"}.get(call["state"], call["state"])
        data = {
            "state": state,
            "name": call["context"],
            "target_url": link,
            "description": call["description"][:255],
        }
        headers = {"PRIVATE-TOKEN": token}
    else:
        raise SendError(f"component {component.name}: no commit status target configured")
    headers["Content-Type"] = "application/json"
    _post(client, url, json.dumps(data).encode(), headers, settings.alert_timeout_s)


def send(
    client: httpx.Client,
    delivery: Delivery,
    settings: Settings,
    subscription: Subscription | None,
    component: Component | None,
) -> None:
    """One try; raises `SendError` saying why it failed. ``client`` is shared by a run's
    threads (`http_client`)."""
    if delivery.kind == "status":
        if component is None:
            raise SendError("the component is gone")
        _status(client, delivery, component, settings)
        return
    if subscription is None:
        raise SendError("the subscription is gone")
    if delivery.kind == "email":
        _mail(delivery, subscription, settings)
    else:
        _webhook(client, delivery, subscription, settings)


def http_client(connections: int) -> httpx.Client:
    """One client for a run's sends: one TLS context and a pool of kept-alive connections (a
    client per call costs ~20 ms of CPU in loading the CA bundle), with TCP_NODELAY (httpx
    writes headers and body apart; without it, Nagle and the receiver's delayed ACK add up to
    40 ms to a small request)."""
    transport = httpx.HTTPTransport(
        limits=httpx.Limits(max_connections=connections * 2, max_keepalive_connections=connections),
        socket_options=[(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)],
    )
    return httpx.Client(transport=transport, follow_redirects=False)


@dataclass
class Leased:
    """A leased delivery with what sending it needs, detached from its session."""

    delivery: Delivery
    subscription: Subscription | None
    component: Component | None


def claim(database_url: str, limit: int, lease: timedelta) -> list[Leased]:
    """Lease up to ``limit`` due deliveries (pending and due, or sending with a lapsed lease),
    each with its subscription and component, in one transaction."""
    now = utcnow()
    with session_scope(database_url) as session:
        supersede(session, now)
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


def deliver_due(database_url: str, settings: Settings, threads: int = 8) -> dict[str, Any]:
    """Send what is due now until nothing is, on ``threads`` threads: leased a few at a time
    (at most one more than each thread sends), each outcome stored as soon as its send ends,
    and what falls due meanwhile taken on while slow sends run. Returns counts and the next
    due time."""
    lease = timedelta(seconds=settings.alert_timeout_s * 3 + 30)
    room = threads * 2
    sent = failed = 0
    in_flight: dict[Future[SendError | None], Leased] = {}
    with http_client(threads) as client, ThreadPoolExecutor(threads) as pool:
        while True:
            if len(in_flight) <= threads:
                for leased in claim(database_url, room - len(in_flight), lease):
                    in_flight[pool.submit(attempt, client, settings, leased)] = leased
            if not in_flight:
                break
            done, _ = wait(in_flight, timeout=POLL_S, return_when=FIRST_COMPLETED)
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
