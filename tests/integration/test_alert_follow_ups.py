"""A subscriber told of a regression hears how it settled (`redline.worker.follow_ups`), and a
digest tells each regression as it is when it goes out: on real Postgres, SMTP and HTTP.

A trial's subscriber was told of a suspected +40 % regression, and never heard that it was
dropped; its digest told a regression fixed since its alert as it had been then."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
from redline.server.db import session_factory
from redline.server.models import DetectionConfigRow, Regression, RegressionState, utcnow
from redline.server.schemas.regressions import TriageRequest
from redline.server.services.regressions import triage
from redline.worker.alerts import PERIOD
from redline.worker.digests import send_digests
from redline.worker.reanalysis import reanalyze_component
from sqlalchemy import select, update

from tests.support import alerting
from tests.support.alerting import alert, eager, revisions, subscribe

SCHEMA = json.loads((Path(__file__).parents[2] / "docs" / "alerts.schema.json").read_text())
api, mailbox, receiver = alerting.api, alerting.mailbox, alerting.receiver  # the fixtures


def _bodies(receiver, path: str) -> list[dict]:
    bodies = [json.loads(call.body) for call in receiver.to(path)]
    for body in bodies:
        jsonschema.validate(body, SCHEMA)
    return bodies


def _digest(api, receiver) -> None:
    """A daily digest by webhook to /digest that wants suspected regressions too."""
    subscribe(
        api,
        {"kind": "webhook", "url": receiver.url + "/digest", "delivery": "digest",
         "confirmed_only": False},
    )  # fmt: skip


def test_a_suspected_regression_that_is_dropped_is_told_as_not_confirmed_once(
    api, tmp_path, receiver, mailbox
):
    subscribe(api, eager(receiver, "/eager"))
    subscribe(api, {"kind": "email", "address": "dev@robots.example", "confirmed_only": False})
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    (first,) = _bodies(receiver, "/eager")
    told = first["alerts"][0]["regression"]
    assert told["confirmation"] == "suspected"

    revisions(api, tmp_path, [10.0, 10.0, 10.0], first=7)  # back at the old level: r6 a spike
    alert(api)
    alert(api)  # and only once
    later = _bodies(receiver, "/eager")[1:]
    assert [body["event"] for body in later] == ["regression.not_confirmed"]
    (settled,) = later[0]["alerts"]
    assert settled["regression"]["id"] == told["id"]
    assert settled["regression"]["confirmation"] == "not_confirmed"
    assert "returned towards the old level" in settled["regression"]["confirmation_reason"]
    assert [(c["counter"], c["confirmation"]) for c in settled["changes"]] == [("cpu", "dropped")]
    assert settled["summary"].startswith("builder: regression not confirmed: component cpu +")

    mails = mailbox.messages
    assert len(mails) == 2
    assert mails[1]["Subject"].startswith("[Redline] builder: regression not confirmed: component")
    assert "r5 and r6: not_confirmed (" in (mails[1].get_body(("plain",)).get_content())


def test_a_suspected_regression_that_holds_is_told_as_confirmed_with_its_figures(
    api, tmp_path, receiver
):
    subscribe(api, eager(receiver, "/eager"))
    subscribe(api, {"kind": "webhook", "url": receiver.url + "/settled"})  # confirmed only
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    revisions(api, tmp_path, [14.0, 14.0], first=7)  # two later revisions hold it
    alert(api)
    alert(api)
    eager_events = [body["event"] for body in _bodies(receiver, "/eager")]
    assert eager_events == ["regression", "regression.confirmed"]
    held = _bodies(receiver, "/eager")[1]["alerts"][0]
    assert held["regression"]["confirmation"] == "confirmed"
    (change,) = held["changes"]
    assert (change["counter"], change["confirmation"], change["revision"]["title"]) == (
        "cpu",
        "held",
        "r6",
    )
    assert change["effect"] > 0.3
    # told once it was confirmed, it has nothing to follow up
    assert [body["event"] for body in _bodies(receiver, "/settled")] == ["regression"]


def test_a_withdrawn_regression_is_told_to_whom_it_was_sent_and_to_no_one_else(
    api, tmp_path, receiver
):
    subscribe(api, eager(receiver, "/eager"))
    _digest(api, receiver)
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:  # judged again, no change of 90 %
        strict = {"methods": ["ks"], "thresholds": {"ks": {"min_effect": 0.9}}}
        session.execute(update(DetectionConfigRow).values(config=strict))
        session.commit()
    reanalyze_component(database_url, 1)
    alert(api)
    alert(api)
    events = [body["event"] for body in _bodies(receiver, "/eager")]
    assert events == ["regression", "regression.withdrawn"]
    (withdrawn,) = _bodies(receiver, "/eager")[1]["alerts"]
    assert withdrawn["regression"]["confirmation"] == "withdrawn"
    assert "none of its changes is found any more" in withdrawn["regression"]["confirmation_reason"]
    assert [c["revision"]["title"] for c in withdrawn["changes"]] == ["r6"]  # as told

    # the digest never sent the regression: it sends nothing of it, withdrawal included
    with session_factory(database_url)() as session:
        assert send_digests(session, now=utcnow() + PERIOD) == []
        session.commit()
    assert receiver.to("/digest") == []


def test_a_digest_tells_a_regression_as_it_is_when_it_goes_out(api, tmp_path, receiver):
    _digest(api, receiver)
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        regression = session.scalar(select(Regression.id))
        triage(session, "builder", regression, TriageRequest(state=RegressionState.fixed), "ada")
        assert len(send_digests(session, now=utcnow() + PERIOD)) == 1
        session.commit()
    alert(api)
    (digest,) = _bodies(receiver, "/digest")
    (told,) = digest["alerts"]
    assert (told["kind"], told["regression"]["state"]) == ("regression", "fixed")
