"""One try of one delivery: a webhook (Redline's JSON or Slack's), a mail, or a commit status
(GitHub's or GitLab's), with a timeout; `SendError` says why a try failed, and whether trying
again can help. The outbox around it: `redline.worker.deliver`.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import smtplib
import socket
import ssl
import time
from email.message import EmailMessage
from email.utils import formatdate
from urllib.parse import quote, urlsplit

import httpx
from redline.recording.format import COMMIT_HASH
from redline.server.core.config import Settings
from redline.server.core.targets import refused_host
from redline.server.models import Component, Delivery, Subscription
from redline.worker import messages

#: a failed webhook try's answer: at most this many bytes read, for at most this many timeouts
ANSWER_BYTES = 4096
ANSWER_TIMES = 3
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


def _post(
    client: httpx.Client, url: str, body: bytes, headers: dict[str, str], timeout: float
) -> None:
    """One POST. Its answer is read for its first `ANSWER_BYTES` at most, and for no longer
    than ``ANSWER_TIMES`` x the timeout (and one more read) in all: the timeout bounds each
    read, and a receiver sending a byte every few seconds held a send thread for ever (a
    review). A failure says the start of it."""
    refused = refused_host(urlsplit(url).hostname or "")
    if refused is not None:  # its answer would land in the delivery log: never asked
        raise SendError(f"refused: {refused}", permanent=True)
    deadline = time.monotonic() + ANSWER_TIMES * timeout
    headers = {**headers, "Accept-Encoding": "identity"}  # read as sent: no zip bomb to unpack
    try:
        with client.stream("POST", url, content=body, headers=headers, timeout=timeout) as answer:
            # read to its end, when short and prompt, the connection goes back to the pool
            said, cut = b"", ""
            for chunk in answer.iter_raw():
                said += chunk
                if len(said) >= ANSWER_BYTES:
                    break
                if time.monotonic() > deadline:
                    cut = f" (cut: no whole answer within {ANSWER_TIMES * timeout:g} s)"
                    break
            if answer.is_success:
                return
    except httpx.InvalidURL as error:  # stored before such URLs were refused: no retry mends it
        raise SendError(f"invalid URL: {error}", permanent=True) from None
    except httpx.HTTPError as error:
        raise SendError(f"{type(error).__name__}: {error}") from None
    text = said[:ANSWER_BYTES].decode(errors="replace")
    raise SendError(f"HTTP {answer.status_code}: {text[:200]}{cut}")


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
        try:
            if settings.smtp_tls == "starttls":
                client.starttls(context=context)
            if settings.smtp_user:
                client.login(settings.smtp_user, settings.smtp_password.get_secret_value())
            client.send_message(mail)
        except BaseException:
            client.close()
            raise
    except (OSError, smtplib.SMTPException) as error:
        raise smtp_failure(error) from None
    try:  # the mail is taken: how the server says goodbye changes nothing (`with` raised on a
        client.quit()  # QUIT answered other than 221, and the mail was sent again: a review)
    except (OSError, smtplib.SMTPException):
        client.close()


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
