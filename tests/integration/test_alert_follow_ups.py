"""A subscriber told of a regression hears how it settled (`redline.worker.follow_ups`), and a
digest tells each regression as it is when it goes out: on real Postgres, SMTP and HTTP.

A trial's subscriber was told of a suspected +40 % regression, and never heard that it was
dropped; its digest told a regression fixed since its alert as it had been then."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import numpy as np
from redline.server.db import session_factory
from redline.server.models import (
    DetectionConfigRow,
    Regression,
    RegressionState,
    RegressionTold,
    Subscription,
    utcnow,
)
from redline.server.schemas.regressions import TriageRequest
from redline.server.services.regressions import triage
from redline.worker.alerts import PERIOD
from redline.worker.digests import send_digests
from redline.worker.reanalysis import reanalyze_component
from sqlalchemy import select, update

from tests.support import alerting
from tests.support.alerting import (
    a_period_later,
    alert,
    cpu_and_rss,
    eager,
    grow_by_rss,
    judged,
    revisions,
    subscribe,
)

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

    # found again (the configuration put back): told again, not left at "withdrawn" (a trial)
    with session_factory(database_url)() as session:
        session.execute(update(DetectionConfigRow).values(config={"methods": ["ks"]}))
        session.commit()
    reanalyze_component(database_url, 1)
    alert(api)
    again = _bodies(receiver, "/eager")[2:]
    assert [body["event"] for body in again] == ["regression"], again
    assert again[0]["alerts"][0]["regression"]["id"] != withdrawn["regression"]["id"]
    assert [c["revision"]["title"] for c in again[0]["alerts"][0]["changes"]] == ["r6"]


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


def _cpu_and_rss(api, tmp_path, means: list[tuple[float, float]], first: int = 1) -> None:
    """Revisions r<first>.. of cpu and rss at these means (2 % noise), judged by KS alone."""
    with session_factory(api.settings.database_url)() as session:
        session.execute(update(DetectionConfigRow).values(config={"methods": ["ks"]}))
        session.commit()
    rng = np.random.default_rng(7 + first)
    runs = [{"cpu": rng.normal(c, c / 50, 60), "rss": rng.normal(r, r / 50, 60)} for c, r in means]
    judged(api, tmp_path, runs, first)


def test_a_follow_up_tells_only_the_changes_the_subscription_keeps(api, tmp_path, receiver):
    """A review's cpu-only subscriber was told "confirmed" of a regression whose cpu change was
    dropped and whose rss change held; the summary named the dropped one."""
    subscribe(api, {**eager(receiver, "/cpu"), "counters": ["cpu"]})
    subscribe(api, eager(receiver, "/all"))
    _cpu_and_rss(api, tmp_path, [(10.0, 100.0)] * 5 + [(14.0, 125.0)])  # both up at r6
    alert(api)
    _cpu_and_rss(api, tmp_path, [(10.0, 125.0)] * 3, first=7)  # cpu back (a spike), rss held
    alert(api)
    assert [b["event"] for b in _bodies(receiver, "/cpu")] == ["regression"]
    everything = _bodies(receiver, "/all")
    assert [b["event"] for b in everything] == ["regression", "regression.confirmed"]
    (held,) = everything[1]["alerts"]
    assert [(c["counter"], c["confirmation"]) for c in held["changes"]] == [("rss", "held")]
    assert held["summary"].startswith("builder: regression confirmed: component rss +")


def test_a_change_that_overshoots_the_old_level_is_no_spike(api, tmp_path):
    """+40 % at r6, then -50 % against it: a regression followed by a fix (or another change),
    not a return to the old level: it stays suspected, not "not confirmed"."""
    revisions(api, tmp_path, [10.0] * 5 + [14.0, 7.0, 7.0, 7.0])
    (regression,) = api.client.get("/api/v1/components/builder/regressions").json()
    assert regression["confirmation"] == "suspected", regression["confirmation_reason"]
    assert "changed again" in regression["confirmation_reason"]


def test_a_follow_up_holds_no_growth_back_and_a_withdrawal_tells_each_change_once(
    api, tmp_path, receiver
):
    subscribe(api, eager(receiver, "/hook"))
    cpu_and_rss(api, tmp_path)  # cpu +40 % at r6, suspected
    alert(api)
    a_period_later(api)
    revisions(api, tmp_path, [14.0, 14.0], first=7)  # held: confirmed
    alert(api)
    grow_by_rss(api)  # rss +3 % flagged at r6 too: the regression grew
    alert(api)
    events = [body["event"] for body in _bodies(receiver, "/hook")]
    assert events == ["regression", "regression.confirmed", "regression.updated"], events

    with session_factory(api.settings.database_url)() as session:  # nothing of 90 % any more
        strict = {"methods": ["ks"], "thresholds": {"ks": {"min_effect": 0.9}}}
        session.execute(update(DetectionConfigRow).values(config=strict))
        session.commit()
    reanalyze_component(api.settings.database_url, 1)
    alert(api)
    last = _bodies(receiver, "/hook")[-1]
    assert last["event"] == "regression.withdrawn"
    told = [(c["counter"], c["revision"]["title"]) for c in last["alerts"][0]["changes"]]
    assert sorted(told) == [("cpu", "r6"), ("rss", "r6")], told  # each once, as told


def test_a_digest_tells_how_a_regression_settled_last_not_on_the_way(api, tmp_path, receiver):
    _digest(api, receiver)
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    database_url = api.settings.database_url

    def digest() -> list[str]:
        with session_factory(database_url)() as session:
            send_digests(session, now=utcnow() + 3 * PERIOD)
            session.commit()
        alert(api)
        (body,) = _bodies(receiver, "/digest")[-1:]
        return [told["kind"] for told in body["alerts"]]

    assert digest() == ["regression"]  # sent while suspected
    with session_factory(database_url)() as session:  # as if a day had passed
        session.execute(update(Subscription).values(digest_sent=utcnow() - 2 * PERIOD))
        session.commit()
    revisions(api, tmp_path, [14.0, 14.0], first=7)  # held: confirmed
    alert(api)
    with session_factory(database_url)() as session:  # then nothing of 90 %: withdrawn
        strict = {"methods": ["ks"], "thresholds": {"ks": {"min_effect": 0.9}}}
        session.execute(update(DetectionConfigRow).values(config=strict))
        session.commit()
    reanalyze_component(database_url, 1)
    alert(api)
    assert digest() == ["regression.withdrawn"]  # not the confirmation it had passed through


def test_what_was_sent_before_the_upgrade_counts_as_told_as_it_stands(api, tmp_path, receiver):
    """Migration 0025: a regression sent before follow-ups existed is recorded as told as it
    stands at the upgrade (a review: every old regression settled since its alert would have
    been followed up at once); one that settles afterwards is followed up."""
    from alembic import command
    from redline.server.db import alembic_config

    subscribe(api, eager(receiver, "/hook"))
    revisions(api, tmp_path, [10.0] * 5 + [14.0])
    alert(api)
    database_url = api.settings.database_url
    config = alembic_config(database_url)
    command.downgrade(config, "0024")  # as the service stood before
    command.upgrade(config, "head")
    with session_factory(database_url)() as session:
        told = session.execute(select(RegressionTold.confirmation)).scalars().all()
    assert told == ["suspected"]
    revisions(api, tmp_path, [14.0, 14.0], first=7)
    alert(api)
    assert [b["event"] for b in _bodies(receiver, "/hook")] == [
        "regression",
        "regression.confirmed",
    ]
