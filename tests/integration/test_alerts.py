"""Alerts end to end on real Postgres, a real SMTP server (STARTTLS and a login) and a real HTTP
receiver: who is told what, once; signatures, retries, slow and dead receivers, a worker killed
mid-send, digests, commit statuses, and the API that manages it all."""

from __future__ import annotations

import hashlib
import hmac
import html
import json
import re
from datetime import timedelta
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from redline.server.db import session_factory
from redline.server.models import (
    Component,
    Delivery,
    Detection,
    DetectionConfigRow,
    Execution,
    Job,
    JobState,
    Regression,
    RegressionState,
    Revision,
    utcnow,
)
from redline.server.schemas.regressions import TriageRequest
from redline.server.services.regressions import triage
from redline.worker.alerts import PERIOD, runtime_alerts, scan_component
from redline.worker.deliver import deliver_due
from redline.worker.detection import detect_revision
from redline.worker.digests import send_digests
from redline.worker.follow_ups import tell_listened
from redline.worker.ingest import ingest_execution
from redline.worker.reanalysis import reanalyze_component
from redline.worker.statuses import commit_status
from redline.worker.sweeps import SWEEP_GRACE, failed_without_status, untold_runtime_alarms
from sqlalchemy import delete, select, update

from tests.support import alerting
from tests.support.alerting import (
    BASE,
    a_period_later,
    alert,
    cpu_and_rss,
    deliveries,
    eager,
    grow_by_rss,
    killed_mid_send,
    revisions,
    scan,
    subscribe,
)
from tests.support.history import add_executions

SCHEMA = json.loads((Path(__file__).parents[2] / "docs" / "alerts.schema.json").read_text())
SECRET = "hook-secret"
SUBJECT = "builder: finer leg association"
api, mailbox, receiver = alerting.api, alerting.mailbox, alerting.receiver  # the fixtures


def test_a_confirmed_regression_is_told_once_by_mail_and_by_signed_webhook(
    api, tmp_path, mailbox, receiver
):
    hook = subscribe(api, {"kind": "webhook", "url": receiver.url + "/hook", "secret": SECRET})
    subscribe(api, {"kind": "email", "address": "dev@robots.example"})
    assert hook["has_secret"] and "secret" not in hook  # never shown again
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    with session_factory(api.settings.database_url)() as session:  # as CI reports it
        session.execute(
            update(Revision).where(Revision.title == "r6").values(message=f"\n{SUBJECT}\n\nWhy.")
        )
        session.commit()
    alert(api)
    assert not receiver.requests and not mailbox.messages  # suspected: not told yet
    revisions(api, tmp_path, [14.0, 14.0], first=7)  # two later revisions hold it
    alert(api)

    (call,) = receiver.to("/hook")
    assert (
        call.headers["X-Redline-Signature-256"]
        == "sha256=" + hmac.new(SECRET.encode(), call.body, hashlib.sha256).hexdigest()
    )
    body = json.loads(call.body)
    jsonschema.validate(body, SCHEMA)
    assert body["delivery"] == call.headers["X-Redline-Delivery"]
    assert body["event"] == "regression" == call.headers["X-Redline-Event"]
    (told,) = body["alerts"]
    assert told["regression"]["confirmation"] == "confirmed"
    assert told["regression"]["page_url"].startswith("https://redline.example/regressions/")
    assert told["regression"]["bad"] == {"title": "r6", "subject": SUBJECT}  # what the commit is
    (change,) = told["changes"]
    assert (change["counter"], change["method"], change["revision"]["title"]) == ("cpu", "ks", "r6")
    assert change["effect"] > 0.3

    (mail,) = mailbox.messages
    assert mailbox.recipients == [["dev@robots.example"]]
    assert "builder" in mail["Subject"] and "cpu" in mail["Subject"]
    assert mail["Message-ID"].startswith("<") and mail["Message-ID"].endswith("@redline>")
    text = mail.get_body(("plain",)).get_content()
    page = mail.get_body(("html",)).get_content()
    assert f"r5 and r6 ('{SUBJECT}'): confirmed" in text, text
    assert told["regression"]["page_url"] in text
    # and where a reader meets the regression (a sixth trial found its commit named nowhere)
    regression = api.client.get(
        f"/api/v1/components/builder/regressions/{told['regression']['id']}"
    ).json()
    assert regression["bad_subject"] == SUBJECT
    assert f"({SUBJECT})" in api.client.get(told["regression"]["page"]).text
    assert f">{SUBJECT}</p>" in api.client.get("/components/builder/revisions/r6").text
    answer = api.client.get("/api/v1/components/builder/revisions/r6").json()
    assert answer["message"] == f"\n{SUBJECT}\n\nWhy."
    assert "https://redline.example/components/builder?" in page

    # a re-analysis, more revisions and a triage never tell it again
    reanalyze_component(api.settings.database_url, 1)
    revisions(api, tmp_path, [14.0], first=9)
    alert(api)
    with session_factory(api.settings.database_url)() as session:
        triage(
            session,
            "builder",
            told["regression"]["id"],
            TriageRequest(state=RegressionState.fixed),
            "ada",
        )
    alert(api)
    assert len(receiver.requests) == 1 and len(mailbox.messages) == 1
    log = deliveries(api, hook["id"])
    assert [(d["state"], d["attempts"], d["event"]) for d in log] == [
        ("delivered", 1, "regression")
    ]


def test_filters_decide_who_hears_and_unconfirmed_can_be_asked_for(api, tmp_path, receiver):
    early = subscribe(api, eager(receiver, "/eager"))
    subscribe(api, {"kind": "webhook", "url": receiver.url + "/rss", "counters": ["rss"]})
    subscribe(api, {"kind": "webhook", "url": receiver.url + "/big", "min_effect": 1.0})
    subscribe(api, {"kind": "webhook", "url": receiver.url + "/better", "direction": "improvement"})
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    (call,) = receiver.requests
    assert call.path == "/eager"
    assert json.loads(call.body)["alerts"][0]["regression"]["confirmation"] == "suspected"
    revisions(api, tmp_path, [8.0, 8.0, 8.0], first=7)  # back down: an improvement, r6 dropped
    alert(api)
    told = {r.path for r in receiver.requests}
    assert told == {"/eager", "/better"}, told
    better = json.loads(receiver.to("/better")[0].body)
    jsonschema.validate(better, SCHEMA)
    assert better["event"] == "improvement" and better["alerts"][0]["regression"] is None
    # no regression page: the revision's (a trial's improvement named its revision by title)
    revision = better["alerts"][0]["changes"][0]["revision"]
    assert revision["page_url"].endswith(f"/components/builder/revisions/{revision['title']}")
    assert deliveries(api, early["id"])[0]["state"] == "delivered"


def test_an_improvement_still_being_judged_holds_back_only_its_own(api, tmp_path, receiver):
    """A review: a revision still being judged held back its improvement, and with it (its
    regression id None in the set of those waiting) every other improvement of the component."""
    subscribe(api, {"kind": "webhook", "url": receiver.url + "/better", "direction": "improvement"})
    revisions(api, tmp_path, [10.0] * 5 + [6.0])
    database_url = api.settings.database_url

    def judged_at(when: object) -> None:
        with session_factory(database_url)() as session:
            session.execute(update(Revision).where(Revision.title == "r6").values(analyzed_at=when))
            session.commit()

    judged_at(None)  # r6 ingested anew, not judged yet
    revisions(api, tmp_path, [3.0], first=7)
    alert(api)
    told = [json.loads(r.body)["alerts"][0]["changes"][0]["revision"]["title"]
            for r in receiver.to("/better")]  # fmt: skip
    assert told == ["r7"], told
    judged_at(utcnow())
    alert(api)
    assert len(receiver.to("/better")) == 2


def test_a_failing_receiver_is_retried_with_the_same_delivery_id_and_told_once(
    api, tmp_path, receiver
):
    receiver.answers["/flaky"] = [500, 503]
    hook = subscribe(api, eager(receiver, "/flaky"))
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    calls = receiver.to("/flaky")
    assert len(calls) == 3
    assert len({c.headers["X-Redline-Delivery"] for c in calls}) == 1
    assert len({c.body for c in calls}) == 1
    (log,) = deliveries(api, hook["id"])
    assert (log["state"], log["attempts"], log["last_error"]) == ("delivered", 3, "")
    alert(api)
    assert len(receiver.to("/flaky")) == 3  # after a success: never again


def test_a_receiver_that_never_answers_in_time_fails_after_its_tries_and_holds_up_no_one(
    api, tmp_path, receiver, mailbox
):
    receiver.delays["/slow"] = 3.0  # the timeout is 1 s
    receiver.answers["/down"] = [500] * 10
    slow = subscribe(api, eager(receiver, "/slow"))
    down = subscribe(api, eager(receiver, "/down"))
    fine = subscribe(api, eager(receiver, "/fine"))
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api, rounds=40)
    assert deliveries(api, fine["id"])[0]["state"] == "delivered"
    (failed,) = deliveries(api, down["id"])
    assert (failed["state"], failed["attempts"]) == ("failed", 5)
    assert failed["last_error"].startswith("HTTP 500")
    (timed_out,) = deliveries(api, slow["id"])
    assert timed_out["state"] == "failed" and "Timeout" in timed_out["last_error"]


def test_an_smtp_server_that_is_down_is_retried_until_it_is_back(api, tmp_path, mailbox):
    mail = subscribe(api, {"kind": "email", "address": "ops@x.example", "confirmed_only": False})
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    working = api.settings
    api.settings = working.model_copy(update={"smtp_port": 1})  # nothing listens there
    with session_factory(working.database_url)() as session:
        scan_component(session, 1)
        session.commit()
    deliver_due(working.database_url, api.settings)
    (log,) = deliveries(api, mail["id"])
    assert log["state"] == "pending" and log["last_error"].startswith("SMTP: ")
    assert log["next_try"] is not None
    api.settings = working
    alert(api)
    assert len(mailbox.messages) == 1
    assert deliveries(api, mail["id"])[0]["state"] == "delivered"


def test_a_worker_killed_mid_send_leaves_it_to_be_sent_again_with_the_same_id(
    api, tmp_path, receiver
):
    receiver.delays["/hook"] = 30.0  # the first try hangs until the worker is killed
    subscribe(api, eager(receiver, "/hook"))
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    scan(api)
    killed_mid_send(api, lambda: receiver.requests)
    (first,) = receiver.requests
    receiver.delays["/hook"] = 0.0
    alert(api)
    again = receiver.requests[1:]
    assert len(again) == 1
    assert again[0].headers["X-Redline-Delivery"] == first.headers["X-Redline-Delivery"]
    assert deliveries(api)[0]["state"] == "delivered"


def test_a_digest_gathers_the_alerts_of_its_period_into_one_message(api, tmp_path, mailbox):
    subscribe(
        api,
        {
            "kind": "email",
            "address": "lead@robots.example",
            "delivery": "digest",
            "confirmed_only": False,
        },
    )
    revisions(api, tmp_path, [10.0] * 5 + [14.0, 14.0, 14.0, 14.0, 20.0])
    alert(api)
    assert not mailbox.messages  # gathered, not sent
    with session_factory(api.settings.database_url)() as session:
        assert send_digests(session) == []  # a day after it was made, not at the next beat
        assert len(send_digests(session, now=utcnow() + PERIOD)) == 1
        assert send_digests(session, now=utcnow() + PERIOD) == []  # once per period
        session.commit()
    alert(api)
    (mail,) = mailbox.messages
    assert mail["Subject"] == "[Redline] digest: 2 alert(s)"
    text = mail.get_body(("plain",)).get_content()
    assert "at r6" in text and "at r10" in text


def test_alerts_waiting_for_a_digest_go_out_when_it_is_switched_to_immediate(
    api, tmp_path, mailbox
):
    """A review: a digest's waiting alerts had no delivery yet, and the digest sender looks
    only at digest subscriptions: switched to immediate, they were never sent."""
    body = {"kind": "email", "address": "lead@robots.example", "delivery": "digest",
            "confirmed_only": False}  # fmt: skip
    ident = subscribe(api, body)["id"]
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    assert not mailbox.messages  # gathered for the digest
    switched = api.client.patch(
        f"{BASE}/subscriptions/{ident}", json={"delivery": "immediate"}, headers=api.tokens["admin"]
    )
    assert switched.status_code == 200, switched.text
    with session_factory(api.settings.database_url)() as session:
        assert len(send_digests(session)) == 1  # at the next beat, not a day later
        assert send_digests(session) == []  # and once
        session.commit()
    alert(api)
    (mail,) = mailbox.messages
    assert mail["Subject"] == "[Redline] digest: 1 alert(s)"
    assert "at r6" in mail.get_body(("plain",)).get_content()


def test_a_digest_leaves_out_a_regression_set_aside_since_its_alert(api, tmp_path, mailbox):
    """A trial's digest told a regression marked a false positive hours before as "confirmed"."""
    subscribe(
        api,
        {"kind": "email", "address": "lead@robots.example", "delivery": "digest",
         "confirmed_only": False},
    )  # fmt: skip
    revisions(api, tmp_path, [10.0] * 5 + [14.0, 14.0, 14.0, 14.0, 20.0])
    alert(api)
    with session_factory(api.settings.database_url)() as session:
        first = session.scalar(select(Regression.id).order_by(Regression.id))
        triage(session, "builder", first, TriageRequest(state="false_positive"), "ada")
        assert len(send_digests(session, now=utcnow() + PERIOD)) == 1
        session.commit()
    alert(api)
    (mail,) = mailbox.messages
    assert mail["Subject"] == "[Redline] digest: 1 alert(s)"
    text = mail.get_body(("plain",)).get_content()
    assert "at r10" in text and "at r6" not in text, text


def test_a_growing_regression_is_updated_once_a_period_with_its_new_series_only(
    api, tmp_path, receiver
):
    subscribe(api, eager(receiver, "/hook"))
    cpu_and_rss(api, tmp_path)
    alert(api)
    (first,) = receiver.requests
    assert [c["counter"] for c in json.loads(first.body)["alerts"][0]["changes"]] == ["cpu"]

    # rss's +3 % is flagged once the floor is lowered: the same regression grew
    grow_by_rss(api)
    alert(api)
    assert len(receiver.requests) == 1  # within the period: told at the next one
    a_period_later(api)
    alert(api)
    alert(api)
    assert len(receiver.requests) == 2
    update_body = json.loads(receiver.requests[1].body)
    jsonschema.validate(update_body, SCHEMA)
    assert update_body["event"] == "regression.updated"
    (grown,) = update_body["alerts"]
    assert [c["counter"] for c in grown["changes"]] == ["rss"]
    assert grown["regression"]["id"] == json.loads(first.body)["alerts"][0]["regression"]["id"]


def test_a_growth_held_back_is_told_by_the_beat_with_no_commit_after_it(api, tmp_path, receiver):
    """A review: the held-back growth waited for a scan, and scans ran only after a detection:
    on a quiet component, days. The digests' beat (every 15 minutes) now scans too."""
    subscribe(api, eager(receiver, "/hook"))
    cpu_and_rss(api, tmp_path)
    alert(api)
    grow_by_rss(api)
    alert(api)
    assert len(receiver.requests) == 1  # within the period
    database_url = api.settings.database_url
    assert tell_listened(database_url) == []  # the beat, still within it
    a_period_later(api)
    assert len(tell_listened(database_url)) == 1  # no detection, no commit: the beat alone
    deliver_due(database_url, api.settings)
    assert [json.loads(r.body)["event"] for r in receiver.requests] == [
        "regression",
        "regression.updated",
    ]


@pytest.mark.parametrize("provider", ["github", "gitlab"])
def test_the_verdict_goes_to_the_commit_status_api(api, tmp_path, receiver, provider):
    repository = "robots/builder"
    answer = api.client.put(
        f"{BASE}/commit-status",
        json={
            "provider": provider,
            "api_url": receiver.url + "/api",
            "repository": repository,
            "token": "tok-123",
        },
        headers=api.tokens["admin"],
    )
    assert answer.status_code == 200 and answer.json()["has_token"], answer.text
    assert "tok-123" not in answer.text
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        session.execute(update(Revision).values(commit="a" * 40))
        session.commit()
        assert len(commit_status(session, 6)) == 1
        assert commit_status(session, 6) == []  # once per revision and state
        session.commit()
    deliver_due(database_url, api.settings)
    (call,) = receiver.requests
    body = json.loads(call.body)
    assert call.method == "POST"
    if provider == "github":
        assert call.path == f"/api/repos/robots/builder/statuses/{'a' * 40}"
        assert call.headers["Authorization"] == "Bearer tok-123"
        assert call.headers["Accept"] == "application/vnd.github+json"
        assert body["state"] == "failure" and body["context"] == "redline/builder"
    else:
        assert call.path == f"/api/projects/robots%2Fbuilder/statuses/{'a' * 40}"
        assert call.headers["Private-Token"] == "tok-123"
        assert body["state"] == "failed" and body["name"] == "redline/builder"
    assert body["target_url"] == "https://redline.example/components/builder/revisions/r6"
    assert "1 change(s) for the worse" in body["description"]


@pytest.mark.parametrize("provider", ["github", "gitlab"])
def test_no_change_posts_success_and_a_revision_still_measured_posts_pending(
    api, tmp_path, receiver, provider
):
    target = {"provider": provider, "api_url": receiver.url + "/api",
              "repository": "robots/builder", "token": "tok-123"}  # fmt: skip
    answer = api.client.put(f"{BASE}/commit-status", json=target, headers=api.tokens["admin"])
    assert answer.status_code == 200, answer.text
    revisions(api, tmp_path, [10.0] * 6)
    waiting = api.revision("r7", "0007")  # its job waits for a performance host
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        session.execute(update(Revision).where(Revision.title == "r6").values(commit="b" * 40))
        # a forge addresses statuses by hash (abbreviated, 7 digits at least): only those get one
        session.execute(update(Revision).where(Revision.title == "r7").values(commit="abc1234"))
        judged = session.scalar(select(Revision.id).where(Revision.title == "r6"))
        assert len(commit_status(session, judged)) == 1
        assert len(commit_status(session, waiting["revision_id"])) == 1
        session.commit()
    deliver_due(database_url, api.settings)
    calls = {call.path.rsplit("/", 1)[1]: call for call in receiver.requests}
    assert set(calls) == {"b" * 40, "abc1234"}
    done, pending = json.loads(calls["b" * 40].body), json.loads(calls["abc1234"].body)
    assert (done["state"], done["description"]) == ("success", "Redline: no change for the worse")
    assert pending["state"] == "pending"
    assert pending["description"] == (
        "Redline: waiting for a performance host to take its jobs (no performance host has "
        "registered yet: start one, docs/running-agents.md)"
    )
    for sha, call in calls.items():
        assert call.method == "POST"
        if provider == "github":
            assert call.path == f"/api/repos/robots/builder/statuses/{sha}"
            assert call.headers["Authorization"] == "Bearer tok-123"
            assert json.loads(call.body)["context"] == "redline/builder"
        else:
            assert call.path == f"/api/projects/robots%2Fbuilder/statuses/{sha}"
            assert call.headers["Private-Token"] == "tok-123"
            assert json.loads(call.body)["name"] == "redline/builder"
        page = "/components/builder/revisions/" + ("r6" if sha == "b" * 40 else "r7")
        assert json.loads(call.body)["target_url"] == "https://redline.example" + page


def test_a_commit_status_target_is_refused_in_words_and_the_stored_one_kept(api, receiver):
    """A repository that is another path of the provider's API, or a token that would break its
    header, is refused naming what is wrong (not a regex), the token never quoted."""
    kept = {"provider": "github", "api_url": receiver.url, "repository": "robots/builder",
            "token": "tok-123"}  # fmt: skip
    assert api.client.put(
        f"{BASE}/commit-status", json=kept, headers=api.tokens["admin"]
    ).is_success
    bad = [
        ({"repository": "../../orgs/x"}, "'..' is not allowed between '/'s"),
        ({"repository": "robots//builder"}, "'' is not allowed between '/'s"),
        ({"repository": "robots/builder/x"}, "on GitHub, owner/name"),
        ({"repository": "robots/build\ner"}, "'\\n' at position 12 is not allowed"),
        ({"repository": "robots/b?x=1"}, "'?' at position 8 is not allowed"),
        ({"token": "tok\r\nX-Evil: 1"}, "must not contain '\\r' at position 3"),
        ({"token": "tok 123"}, "must not contain ' ' at position 3"),
    ]
    for change, said in bad:
        answer = api.client.put(
            f"{BASE}/commit-status", json={**kept, **change}, headers=api.tokens["admin"]
        )
        said_back = " ".join(error["msg"] for error in answer.json()["detail"])
        assert answer.status_code == 422 and said in said_back, (change, answer.text)
        assert "pattern" not in answer.text and "tok" not in answer.text.replace("token", "")
    group = {**kept, "provider": "gitlab", "repository": "robots/arms/builder"}
    assert api.client.put(
        f"{BASE}/commit-status", json=group, headers=api.tokens["admin"]
    ).is_success
    stored = api.client.get(f"{BASE}/commit-status", headers=api.tokens["admin"]).json()
    assert stored["repository"] == "robots/arms/builder"


def test_an_address_or_an_empty_field_is_refused_in_words(api):
    bad = [
        ("dev team@robots.example", "must not contain ' ' at position 3"),
        ("dev@robots.example\nBcc: x@y.z", "must not contain '\\n' at position 18"),
        ("dev@robots", "must be one address, as name@example.org"),
        ("a@b@robots.example", "must be one address, as name@example.org"),
        ("<dev@robots.example>", "'<' at position 0"),
    ]
    for address, said in bad:
        answer = api.post(f"{BASE}/subscriptions", "admin", {"kind": "email", "address": address})
        said_back = " ".join(error["msg"] for error in answer.json()["detail"])
        assert answer.status_code == 422 and said in said_back, (address, answer.text)
        assert "pattern" not in answer.text
    empty = {"component": "builder", "title": "r1", "sort_key": "", "commit": "abc1234"}
    answer = api.post("/api/v1/revisions", "ci", empty)
    assert answer.status_code == 422 and answer.json()["detail"][0]["msg"] == "must not be empty"


def test_subscriptions_are_admin_only_checked_and_listed_changed_and_deleted(api, receiver):
    hook = {"kind": "webhook", "url": receiver.url + "/hook", "secret": "s"}
    for scope in ("ci", "triage", "read", "agent"):
        answer = api.post(f"{BASE}/subscriptions", scope, hook)
        assert answer.status_code == 403, answer.text
    bad = [
        ({"kind": "webhook", "url": "file:///etc/passwd"}, "http:// or https://"),
        ({"kind": "webhook"}, "url: a webhook subscription needs one"),
        ({"kind": "email"}, "address: an email subscription needs one"),
        ({"kind": "email", "address": "a@b.example", "url": "https://x.example"}, "takes none"),
        ({"kind": "email", "address": "not an address"}, "address"),
        ({"kind": "pager", "address": "x@y.z"}, "kind"),
        ({**hook, "direction": "sideways"}, "direction"),
        ({**hook, "min_effect": -1}, "min_effect"),
        ({**hook, "confirmedonly": False}, "confirmedonly"),  # a misspelt filter
    ]
    for body, said in bad:
        answer = api.post(f"{BASE}/subscriptions", "admin", body)
        assert answer.status_code == 422 and said in answer.text, (body, answer.text)
    leaked = api.post(
        f"{BASE}/subscriptions",
        "admin",
        {"kind": "webhook", "url": "file:///x", "secret": "TOPSECRET", "confirmedonly": 1},
    )
    assert leaked.status_code == 422 and "TOPSECRET" not in leaked.text, leaked.text
    assert api.post("/api/v1/components/nobody/subscriptions", "admin", hook).status_code == 404
    made = subscribe(api, hook)
    everywhere = subscribe(api, {"kind": "email", "address": "all@robots.example"}, None)
    assert everywhere["component"] is None
    # the same address or URL again, where it is subscribed: every alert would go twice (a
    # trial's second subscription of one address was taken)
    for scope, body in (
        (BASE, hook),
        ("/api/v1", {"kind": "email", "address": "ALL@robots.example"}),
    ):
        again = api.post(f"{scope}/subscriptions", "admin", body)
        assert again.status_code == 409 and "is subscribed already" in again.text, again.text
    listed = api.client.get(f"{BASE}/subscriptions", headers=api.tokens["admin"]).json()
    assert [s["id"] for s in listed] == [made["id"]] and '"secret"' not in json.dumps(listed)
    changed = api.client.patch(
        f"{BASE}/subscriptions/{made['id']}",
        json={"direction": "any", "delivery": "digest"},
        headers=api.tokens["admin"],
    ).json()
    assert (changed["direction"], changed["delivery"], changed["has_secret"]) == (
        "any",
        "digest",
        True,
    )
    mail = api.client.patch(
        f"/api/v1/subscriptions/{everywhere['id']}",
        json={"url": "https://x.example/hook"},
        headers=api.tokens["admin"],
    )
    assert mail.status_code == 422 and "takes none" in mail.text  # a url on a mail subscription
    for null in ({"url": None}, {"counters": None, "direction": "regression"}):
        kept = api.client.patch(
            f"{BASE}/subscriptions/{made['id']}", json=null, headers=api.tokens["admin"]
        )
        assert kept.status_code == 422 and "null changes nothing" in kept.text, kept.text
    stored = api.client.get(f"{BASE}/subscriptions/{made['id']}", headers=api.tokens["admin"])
    assert (stored.json()["url"], stored.json()["direction"]) == (hook["url"], "any")
    gone = api.client.delete(f"{BASE}/subscriptions/{made['id']}", headers=api.tokens["admin"])
    assert gone.status_code == 204
    again = api.client.get(f"{BASE}/subscriptions/{made['id']}", headers=api.tokens["admin"])
    assert again.status_code == 404 and "no subscription" in again.text


def test_imported_results_alert_when_flagged_and_slack_gets_its_own_format(api, tmp_path, receiver):
    """No agent can re-run imported results, so their regressions cannot wait for confirmation
    runs: a confirmed-only subscription hears of them when flagged."""
    subscribe(api, {"kind": "webhook", "url": receiver.url + "/slack", "format": "slack"})
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    assert not receiver.requests  # measured by an agent: waits for its confirmation
    with session_factory(api.settings.database_url)() as session:
        session.execute(update(Execution).values(meta={"imported": "results"}))
        session.commit()
    alert(api)
    (call,) = receiver.requests
    body = json.loads(call.body)
    assert set(body) == {"text"}  # what Slack-compatible incoming webhooks take
    assert body["text"].startswith("*Redline*\n<https://redline.example/regressions/")
    assert "|builder: regression: " in body["text"] and "cpu +" in body["text"]


def test_a_wrong_token_is_refused_even_where_reading_is_open(api):
    path = f"{BASE}/revisions/r1/verdict"
    wrong = api.client.get(path, headers={"Authorization": "Bearer rl_mistyped"})
    assert wrong.status_code == 401 and "invalid or revoked token" in wrong.text
    # in the address as in the header (a trial from outside found it ignored there)
    wrong = api.client.get(f"{path}?token=rl_mistyped")
    assert wrong.status_code == 401 and "invalid or revoked token" in wrong.text
    assert api.client.get(path).status_code == 404  # no token: open reading, no such revision


def test_a_runtime_fault_reaches_the_subscriptions_that_want_its_target_once(
    api, mailbox, receiver
):
    hook = subscribe(api, {"kind": "webhook", "url": receiver.url + "/hook"})
    subscribe(api, {"kind": "email", "address": "mem@robots.example", "counters": ["rss_bytes"]})
    fault = {"target": "cpu_percent", "started": True, "residual": 61.5, "threshold": 4.0,
             "step": 60, "host": "robot-1", "process": "objectbuilder"}  # fmt: skip
    for field in ("step", "model"):  # past 32 bits: refused by name, not "cannot be stored"
        huge = api.post(f"{BASE}/runtime-alerts", "agent", {**fault, field: 10**20})
        assert huge.status_code == 422 and huge.json()["detail"][0]["loc"] == ["body", field]
    # an audit's CR/LF in the target made every mail of the alert fail (a header cannot hold it)
    for field, text in (("target", "cpu\r\nBcc: x@y.example"), ("process", "a\u202eb")):
        broken = api.post(f"{BASE}/runtime-alerts", "agent", {**fault, field: text})
        assert broken.status_code == 422, broken.text
        assert broken.json()["detail"][0]["loc"] == ["body", field], broken.text
    answer = api.post(f"{BASE}/runtime-alerts", "agent", fault)
    assert answer.status_code == 201, answer.text
    database_url = api.settings.database_url
    later = utcnow() + SWEEP_GRACE + timedelta(seconds=5)
    with session_factory(database_url)() as session:
        # its task is on its way: the sweep leaves it; had it been lost, the sweep queues it
        assert untold_runtime_alarms(session) == []
        assert untold_runtime_alarms(session, now=later) == [answer.json()["id"]]
    for _ in range(2):  # a retried task tells no one twice
        with session_factory(database_url)() as session:
            runtime_alerts(session, answer.json()["id"])
            session.commit()
    with session_factory(database_url)() as session:
        assert untold_runtime_alarms(session, now=later) == []  # told
    deliver_due(database_url, api.settings)

    (call,) = receiver.to("/hook")
    body = json.loads(call.body)
    jsonschema.validate(body, SCHEMA)
    assert body["event"] == "runtime_fault" == call.headers["X-Redline-Event"]
    (told,) = body["alerts"]
    assert told["summary"] == (
        "builder: run-time fault: cpu_percent above what its traffic predicts by 61.5 "
        "(threshold 4) (objectbuilder on robot-1)"
    )
    assert (
        told["runtime"]["page_url"] == "https://redline.example/components/builder#runtime-alerts"
    )
    assert not mailbox.messages  # that subscription wants rss_bytes only
    assert [d["event"] for d in deliveries(api, hook["id"])] == ["runtime_fault"]

    # its end, and a leak, reach the mail subscription too; one made later hears nothing earlier
    ended = api.post(f"{BASE}/runtime-alerts", "agent", {**fault, "started": False}).json()
    leak = api.post(
        f"{BASE}/runtime-alerts", "agent", {**fault, "target": "rss_bytes", "residual": 9e6}
    ).json()
    subscribe(api, {"kind": "webhook", "url": receiver.url + "/later"})
    with session_factory(database_url)() as session:
        for alarm in (ended, leak):
            runtime_alerts(session, alarm["id"])
        session.commit()
    deliver_due(database_url, api.settings)
    told = sorted(json.loads(c.body)["event"] for c in receiver.to("/hook"))  # sent side by side
    assert told == ["runtime_fault", "runtime_fault", "runtime_fault.over"]
    (mail,) = mailbox.messages
    assert mail["Subject"].startswith("[Redline] builder: run-time fault: rss_bytes above")
    assert (
        "https://redline.example/components/builder#runtime-alerts"
        in mail.get_body(("plain",)).get_content()
    )
    assert not receiver.to("/later")


def test_a_revision_whose_jobs_all_failed_gets_its_commit_status_too(api, receiver):
    api.client.put(
        f"{BASE}/commit-status",
        json={
            "provider": "github",
            "api_url": receiver.url + "/api",
            "repository": "r/b",
            "token": "tok",
        },  # fmt: skip
        headers=api.tokens["admin"],
    ).raise_for_status()
    revision = api.revision("r1", "1")
    api.post("/api/v1/agent/register", "agent", {"name": "perf1"}).raise_for_status()
    job = api.lease()
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:  # a hash: what a status is addressed by
        session.execute(update(Revision).values(commit="abc1234"))
        session.commit()
    with session_factory(database_url)() as session:
        assert failed_without_status(session) == []  # still running: its verdict may come
    answer = api.post(f"/api/v1/jobs/{job['id']}/fail", "agent", {"host": "perf1", "reason": "x"})
    assert answer.status_code == 200, answer.text
    # no ingest follows a failed job: the API itself queues the verdict's scan ...
    assert ("redline.scan_alerts", f"[None, {revision['revision_id']}]") in api.queued_tasks()
    later = utcnow() + SWEEP_GRACE + timedelta(seconds=5)
    with session_factory(database_url)() as session:
        # ... and the periodic sweep finds it too, should that message be lost (once the
        # message has had time to arrive)
        assert failed_without_status(session) == []
        assert failed_without_status(session, now=later) == [revision["revision_id"]]
        assert len(commit_status(session, revision["revision_id"])) == 1
        session.commit()
        assert failed_without_status(session, now=later) == []  # posted once
    deliver_due(database_url, api.settings)
    (call,) = receiver.requests
    body = json.loads(call.body)
    assert call.path == "/api/repos/r/b/statuses/abc1234"
    assert body["state"] == "error" and "failed or were cancelled" in body["description"]
    with session_factory(database_url)() as session:
        # a component that posts no statuses has nothing swept, however its jobs ended
        session.execute(delete(Delivery))
        session.execute(update(Component).values(commit_status={}))
        session.commit()
        assert failed_without_status(session, now=later) == []


def test_a_change_is_told_once_every_execution_of_its_revision_is_in(api, tmp_path, receiver):
    """A trial's regression was told with 6 series; the revision's third execution, in 12 s
    later, made it 7, and the 7th was left to a daily update."""
    subscribe(api, eager(receiver, "/hook"))
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    with session_factory(api.settings.database_url)() as session:
        r6 = session.scalars(select(Revision).where(Revision.title == "r6")).one()
        third = Job(revision_id=r6.id, execution_index=9, labels=[])  # still to run
        session.add(third)
        session.commit()
        third_id = third.id
    alert(api)
    assert not receiver.requests  # r6 is still being measured
    with session_factory(api.settings.database_url)() as session:
        session.execute(update(Job).where(Job.id == third_id).values(state=JobState.failed))
        session.commit()
    alert(api)
    (told,) = receiver.to("/hook")
    assert json.loads(told.body)["alerts"][0]["changes"][0]["revision"]["title"] == "r6"


def test_the_revision_page_states_the_ci_gate_and_the_regression_behind_it(api, tmp_path):
    """A trial read a confirmed regression's revision page and found no word of whether CI
    passed: only `redline ci` and /verdict said it."""
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    verdict = api.client.get(f"{BASE}/revisions/r6/verdict").json()
    found = api.client.get(f"{BASE}/detections", params={"revision": "r6"}).json()
    (number,) = {d["regression_id"] for d in found if d["regression_id"]}
    page = html.unescape(api.client.get("/components/builder/revisions/r6").text)
    said = f"CI gate: fails: {verdict['regressions']} change for the worse in 1 test case of 1"
    assert said in page and f'<a href="/regressions/{number}">#{number}</a>' in page
    earlier = html.unescape(api.client.get("/components/builder/revisions/r5").text)
    assert "CI gate: passes: 1 test case of 1 passed; redline ci exits 0." in earlier
    first = html.unescape(api.client.get("/components/builder/revisions/r1").text)
    assert "CI gate: passes, nothing judged yet: 1 test case without a verdict yet" in first


def test_a_regression_judged_again_without_its_change_is_withdrawn_with_its_figures(api, tmp_path):
    """A trial's untriaged regression was deleted when its revision was judged again, leaving
    no record, and the alert's link to it led nowhere: it is kept, withdrawn, with what it had
    been; a change found again later opens a regression of its own, the withdrawn one keeping
    its old range out of it."""
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    (before,) = api.client.get(f"{BASE}/regressions").json()
    assert before["confirmation"] == "suspected"
    said = before["confirmation_reason"]
    assert re.search(
        r"; the largest: throughput/publish: component cpu \[rate=10\] \+\d+\.\d % at r6$", said
    ), said
    counted = '<a href="/regressions?component=builder&amp;state=open">1</a>'
    assert counted in api.client.get("/").text  # the home page's open regressions
    database_url = api.settings.database_url

    def judge_with(min_effect: float) -> None:
        config = {"methods": ["ks"], "thresholds": {"ks": {"min_effect": min_effect}}}
        with session_factory(database_url)() as session:
            session.execute(update(DetectionConfigRow).values(config=config))
            session.commit()
        reanalyze_component(database_url, 1)

    judge_with(0.9)  # no change of 40 % is one of 90 %
    (withdrawn,) = api.client.get(f"{BASE}/regressions").json()
    assert (withdrawn["id"], withdrawn["confirmation"]) == (before["id"], "withdrawn")
    reason = withdrawn["confirmation_reason"]
    assert "none of its changes is found any more" in reason
    assert reason.endswith(f"it had been suspected: {before['confirmation_reason']}")
    listed = api.client.get(f"{BASE}/regressions", params={"confirmation": "withdrawn"}).json()
    assert [r["id"] for r in listed] == [before["id"]]
    # nor is it in the triage queue, where it had been new
    assert api.client.get(f"{BASE}/regressions", params={"state": "new"}).json() == []
    assert "No regression matches." in api.client.get("/regressions?state=new").text
    page = html.unescape(api.client.get(f"/regressions/{before['id']}").text)
    assert "withdrawn" in page and before["confirmation_reason"] in page
    assert "None now: judged again, its revisions no longer show any of its changes" in page
    assert 'id="flagged"' not in page  # no empty table
    assert counted not in api.client.get("/").text  # not open: the home page counts 0

    judge_with(0.1)
    found = {r["id"]: r["confirmation"] for r in api.client.get(f"{BASE}/regressions").json()}
    assert found.pop(before["id"]) == "withdrawn"
    assert list(found.values()) == ["suspected"]


def test_a_run_ingested_as_its_detection_began_and_judged_by_it_is_told(
    api, tmp_path, receiver, monkeypatch
):
    """A review: the alerts took a revision for unjudged while a run of it was updated after
    its `analyzed_at`, which is when its detection began: a run ingested just after that, but
    read by that detection, held the change's alert back until the revision was judged again.
    Whether a revision is judged is its mark alone now (`redline.server.services.analysed`)."""
    from redline.worker import detection

    subscribe(api, eager(receiver, "/hook"))
    revisions(api, tmp_path, [10.0] * 5)
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        runs = [{"cpu": np.random.default_rng(2).normal(15.0, 0.3, 60)}]
        (late,) = add_executions(session, tmp_path, "builder", "r6", "6", runs)
    seen = detection.inputs_seen

    def ingest_first(session, revision_ids):  # after the detection's start time was taken
        ingest_execution(database_url, late.id)
        return seen(session, revision_ids)

    monkeypatch.setattr(detection, "inputs_seen", ingest_first)
    detect_revision(database_url, late.revision_id)
    with session_factory(database_url)() as session:
        judged = session.get_one(Revision, late.revision_id).analyzed_at
        updated = session.scalar(select(Job.updated).where(Job.id == late.job_id))
    assert judged is not None and updated > judged  # judged with it, marked as it began
    alert(api)
    assert receiver.to("/hook"), "the change judged from every run was not told"


def test_a_change_is_told_once_every_ingested_execution_is_judged(api, tmp_path, receiver):
    """A third trial's alert said +85.6 %, the median of two of r6's three executions, where the
    verdict of all three said +80.4 %: the scan ran after the third's ingestion, before its
    judging. It now waits for that judging."""
    subscribe(api, eager(receiver, "/hook"))
    revisions(api, tmp_path, [10.0] * 5)
    answer = api.client.patch(
        "/api/v1/components/builder", json={"executions": 3}, headers=api.tokens["admin"]
    )
    assert answer.status_code == 200, answer.text
    rng = np.random.default_rng(1)
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        runs = [{"cpu": rng.normal(level, 0.3, 60)} for level in (14.0, 15.0, 12.0)]
        first, second, third = add_executions(session, tmp_path, "builder", "r6", "6", runs)
    for execution in (first, second):
        ingest_execution(database_url, execution.id)
    detect_revision(database_url, first.revision_id)  # judged on two executions
    ingest_execution(database_url, third.id)  # the third is in, not yet judged
    alert(api)
    assert not receiver.requests  # its verdict is not yet the one of every execution
    detect_revision(database_url, first.revision_id)
    alert(api)
    (told,) = receiver.to("/hook")
    (change,) = json.loads(told.body)["alerts"][0]["changes"]
    with session_factory(database_url)() as session:  # the verdict of all three executions
        stored = session.scalars(
            select(Detection.effect)
            .join(Revision, Revision.id == Detection.revision_id)
            .where(Revision.title == "r6", Detection.flagged)
        ).one()
    assert change["effect"] == pytest.approx(stored)
