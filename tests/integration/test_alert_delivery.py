"""Delivering alerts when the other end misbehaves, on real Postgres, a real SMTP server (aiosmtpd,
STARTTLS and a login) and a real HTTP receiver: a mail server that answers 4xx, refuses for good
(5xx), is slow, or loses its worker mid-mail; a webhook receiver whose port is closed; a success
that comes in after its lease lapsed; a URL aimed at the cloud's metadata service."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta
from pathlib import Path

import pytest
from redline.agent.network import free_port
from redline.server.db import session_factory
from redline.server.models import Delivery, Subscription
from redline.worker.deliver import attempt, claim, deliver_due, record
from redline.worker.sending import http_client
from sqlalchemy import update

from tests.support import alerting
from tests.support.alerting import (
    alert,
    deliveries,
    eager,
    killed_mid_send,
    revisions,
    scan,
    subscribe,
)
from tests.support.api import Api

api, mailbox, receiver = alerting.api, alerting.mailbox, alerting.receiver  # the fixtures
MAIL = {"kind": "email", "address": "ops@x.example", "confirmed_only": False}


def failed_once(api: Api, tmp_path: Path, subscription: dict) -> tuple[int, str]:
    """Subscribe, flag a regression at r6, and try its delivery once (a failure waits an hour:
    nothing is tried twice), which must fail; then make it due again. Returns the
    subscription's id and the try's error."""
    ident = subscribe(api, subscription)["id"]
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    scan(api)
    patient = api.settings.model_copy(update={"alert_retry_s": 3600.0})
    deliver_due(api.settings.database_url, patient)
    (log,) = deliveries(api, ident)
    assert (log["state"], log["attempts"]) == ("pending", 1), log
    with session_factory(api.settings.database_url)() as session:
        session.execute(update(Delivery).values(next_try=Delivery.created))
        session.commit()
    return ident, log["last_error"]


@pytest.mark.parametrize("command", ["RCPT", "DATA"])
def test_an_smtp_server_answering_451_is_tried_again_and_the_mail_taken_once(
    api, tmp_path, mailbox, command
):
    mailbox.answers[command] = ["451 4.7.1 greylisted, try again later"]
    mail, error = failed_once(api, tmp_path, MAIL)
    assert "451 4.7.1 greylisted, try again later" in error, error
    assert not mailbox.messages
    alert(api)
    (log,) = deliveries(api, mail)
    assert (log["state"], log["attempts"], log["last_error"]) == ("delivered", 2, "")
    (taken,) = mailbox.messages
    # refused at DATA, the mail came twice, the same Message-ID both times
    assert len(mailbox.arrived) == (2 if command == "DATA" else 1)
    assert {m["Message-ID"] for m in mailbox.arrived} == {taken["Message-ID"]}
    alert(api)
    assert len(mailbox.messages) == 1  # never again after the success


@pytest.mark.parametrize(
    ("command", "reply", "said"),
    [
        (
            "RCPT",
            "550 5.1.1 <ops@x.example>: no such user here",
            "SMTP: recipient refused: ops@x.example: 550 5.1.1 <ops@x.example>: no such user here",
        ),
        ("DATA", "554 5.7.1 rejected as spam", "SMTP: mail refused: 554 5.7.1 rejected as spam"),
    ],
)
def test_an_smtp_server_refusing_the_mail_for_good_fails_it_at_once_with_its_reply(
    api, tmp_path, mailbox, command, reply, said
):
    """A 5xx to the mail is the server's last word: ten tries would be refused ten times."""
    mailbox.answers[command] = [reply] * 10
    mail = subscribe(api, MAIL)
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    (log,) = deliveries(api, mail["id"])
    assert (log["state"], log["attempts"], log["last_error"]) == ("failed", 1, said)
    assert not mailbox.messages
    assert mailbox.answers[command] == [reply] * 9  # asked once


def test_a_slow_smtp_server_times_out_and_is_tried_again(api, tmp_path, mailbox):
    mailbox.delays["RCPT"] = 3.0  # the timeout is 1 s
    mail, error = failed_once(api, tmp_path, MAIL)
    assert "timed out" in error, error
    assert not mailbox.arrived
    mailbox.delays["RCPT"] = 0.0
    alert(api)
    (log,) = deliveries(api, mail)
    assert (log["state"], log["attempts"]) == ("delivered", 2)
    assert len(mailbox.messages) == 1


def test_a_worker_killed_mid_mail_sends_it_again_with_the_same_message_id(api, tmp_path, mailbox):
    mailbox.delays["DATA"] = 30.0  # the mail is in; the answer waits until the worker is killed
    mail = subscribe(api, MAIL)
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    scan(api)
    killed_mid_send(api, lambda: mailbox.arrived)
    (first,) = mailbox.arrived
    assert not mailbox.messages  # never answered
    mailbox.delays["DATA"] = 0.0
    alert(api)
    assert len(mailbox.arrived) == 2
    assert mailbox.arrived[1]["Message-ID"] == first["Message-ID"]  # the receiver can tell
    (taken,) = mailbox.messages
    assert taken["X-Redline-Delivery"] == first["X-Redline-Delivery"]
    (log,) = deliveries(api, mail["id"])
    assert (log["state"], log["attempts"]) == ("delivered", 2)


def test_a_webhook_receiver_refusing_connections_is_tried_again_and_the_log_says_refused(
    api, tmp_path
):
    closed = f"http://127.0.0.1:{free_port()}/hook"  # nothing listens there
    hook, error = failed_once(api, tmp_path, {"kind": "webhook", "url": closed,
                                              "confirmed_only": False})  # fmt: skip
    assert error.startswith("ConnectError: ") and "refused" in error, error
    alert(api, rounds=40)
    (log,) = deliveries(api, hook)
    assert (log["state"], log["attempts"]) == ("failed", 5)  # every try, then given up
    assert "refused" in log["last_error"]


def test_a_success_that_comes_after_its_lease_lapsed_is_kept_and_never_sent_again(
    api, tmp_path, receiver
):
    """A slow batch outlived its lease: another worker took the delivery and failed, and the
    first worker's success came in after that failure was stored. Before, that success was
    thrown away and the receiver was sent the message again after taking it."""
    hook = subscribe(api, eager(receiver, "/hook"))
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    scan(api)
    database_url = api.settings.database_url
    (first,) = claim(database_url, 10, lease=timedelta(0))  # lapses as soon as it is taken
    with http_client(1) as client:
        assert attempt(client, api.settings, first) is None  # taken; not yet stored
        receiver.answers["/hook"] = [500]
        (second,) = claim(database_url, 10, lease=timedelta(minutes=5))  # another worker
        failure = attempt(client, api.settings, second)
    assert failure is not None and str(failure).startswith("HTTP 500")
    record(database_url, api.settings, [(second, failure)])
    record(database_url, api.settings, [(first, None)])
    (log,) = deliveries(api, hook["id"])
    assert (log["state"], log["attempts"], log["last_error"]) == ("delivered", 2, "")
    alert(api)
    assert len(receiver.to("/hook")) == 2  # the success and the other worker's try; no more
    # a failure stored after the success leaves it delivered
    record(database_url, api.settings, [(second, failure)])
    assert deliveries(api, hook["id"])[0]["state"] == "delivered"


METADATA = "http://169.254.169.254/latest/meta-data/iam/security-credentials/"


def test_a_url_aimed_at_the_metadata_service_is_refused_when_set_and_never_asked(
    api, tmp_path, receiver
):
    """What a webhook's receiver answers lands in the delivery log: a URL aimed at the host's
    metadata service would read its credentials there. The API refuses one (422, naming it); one
    stored before that check, or a name that resolves there, fails at once, never asked."""
    for url in (METADATA, "http://[fe80::1]/hook", "http://[::ffff:169.254.169.254]/"):
        answer = api.post("/api/v1/components/builder/subscriptions", "admin",
                          {"kind": "webhook", "url": url})  # fmt: skip
        assert answer.status_code == 422, answer.text
        assert "link-local or cloud metadata address" in answer.text, answer.text
        assert "Value error" not in answer.text, answer.text
    hook = subscribe(api, eager(receiver, "/hook"))["id"]
    with session_factory(api.settings.database_url)() as session:  # as stored before the check
        session.execute(update(Subscription).values(url=METADATA))
        session.commit()
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    (log,) = deliveries(api, hook)
    assert (log["state"], log["attempts"]) == ("failed", 1), log
    assert log["last_error"] == (
        "refused: 169.254.169.254 is a link-local or cloud metadata address"
    ), log
    assert not receiver.to("/hook")


def test_a_receiver_trickling_its_answer_is_cut_off_and_its_try_failed(api, tmp_path, receiver):
    """A review: the timeout bounds each read, so an answer of a byte every few seconds held a
    send thread for ever. A failed try reads its answer for at most 3 timeouts (here 1 s)."""
    receiver.answers["/drip"] = [500]
    receiver.drips["/drip"] = 0.4  # its 17 bytes take 7 s; each well within the 1 s timeout
    _, error = failed_once(api, tmp_path, eager(receiver, "/drip"))
    assert error.startswith('HTTP 500: {"err') and '"down"}' not in error, error
    assert error.endswith("(cut: no whole answer within 3 s)"), error


def test_a_send_under_way_keeps_its_lease_and_no_other_run_sends_it_too(api, tmp_path, receiver):
    """A review: a receiver slower than the lease had its delivery taken by another run, and
    then another, until every send thread waited on it."""
    receiver.delays["/slow"] = 2.5  # longer than the lease below, within the timeout
    hook = subscribe(api, eager(receiver, "/slow"))
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    scan(api)
    patient = api.settings.model_copy(update={"alert_timeout_s": 10.0})
    database_url = api.settings.database_url
    with ThreadPoolExecutor(1) as pool:  # one run, its lease 0.6 s, renewed while it sends
        running = pool.submit(deliver_due, database_url, patient, 2, timedelta(seconds=0.6))
        while not receiver.to("/slow"):
            time.sleep(0.05)
        for _ in range(8):  # another run looks, the first lease long lapsed
            time.sleep(0.25)
            assert claim(database_url, 10, timedelta(minutes=5)) == [], "taken twice"
        assert running.result(timeout=60)["sent"] == 1
    (log,) = deliveries(api, hook["id"])
    assert (log["state"], log["attempts"]) == ("delivered", 1)
    assert len(receiver.to("/slow")) == 1


def test_a_delivery_whose_worker_stopped_on_its_last_try_is_failed_not_sent_again(
    api, tmp_path, receiver
):
    hook = subscribe(api, eager(receiver, "/hook"))
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    scan(api)
    database_url = api.settings.database_url
    (taken,) = claim(database_url, 10, lease=timedelta(0), max_attempts=1)  # then it "died"
    assert claim(database_url, 10, lease=timedelta(minutes=5), max_attempts=1) == []
    (log,) = deliveries(api, hook["id"])
    assert (log["state"], log["attempts"]) == ("failed", 1), log
    assert "its lease lapsed on its last try (1): the worker stopped mid-send" in log["last_error"]
    assert receiver.to("/hook") == [] and taken.delivery.attempts == 1


def test_a_mail_taken_is_delivered_however_the_server_answers_quit(api, tmp_path, mailbox):
    """A review: smtplib's `with` raises when QUIT is answered other than 221, after the mail
    was taken; the try counted as failed and the mail was sent again, up to ten times."""
    mailbox.answers["QUIT"] = ["421 4.3.2 shutting down"]
    ident = subscribe(api, MAIL)["id"]
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    assert len(mailbox.messages) == 1
    (log,) = deliveries(api, ident)
    assert (log["state"], log["attempts"], log["last_error"]) == ("delivered", 1, "")
