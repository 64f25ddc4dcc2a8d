"""Commit statuses of one revision whose state moves (a late arrival has it judged again): the
commit must end at the last verdict, whatever order scans and sends run in. Real Postgres and a
real HTTP receiver (`tests.support.alerting`)."""

from __future__ import annotations

import json
import threading
from datetime import timedelta

from redline.server.db import session_factory
from redline.server.models import Delivery, Revision, utcnow
from redline.worker.deliver import deliver_due
from redline.worker.statuses import commit_status
from sqlalchemy import select, update

from tests.support import alerting
from tests.support.alerting import BASE, revisions

api, mailbox, receiver = alerting.api, alerting.mailbox, alerting.receiver  # the fixtures
TARGET = {"provider": "github", "repository": "robots/builder", "token": "tok-123"}


def _target(api, receiver) -> None:
    answer = api.client.put(
        f"{BASE}/commit-status",
        json={**TARGET, "api_url": receiver.url + "/api"},
        headers=api.tokens["admin"],
    )
    assert answer.status_code == 200, answer.text


def test_a_revision_judged_again_gets_its_status_back_after_pending(api, tmp_path, receiver):
    """A late arrival has r6 judged again (pending meanwhile): once per revision and state
    would leave its commit at pending for good; and statuses of one commit made faster than
    they are sent must not land out of order: the older ones not sent yet are superseded."""
    _target(api, receiver)
    revisions(api, tmp_path, [10.0] * 6)
    database_url = api.settings.database_url

    def judged_again(title: str, analysed: list[bool], send_each: bool) -> list[int]:
        made = []
        with session_factory(database_url)() as session:
            session.execute(update(Revision).values(commit="c" * 40))
            revision = session.scalar(select(Revision.id).where(Revision.title == title))
            for done in analysed:
                at = utcnow() if done else None
                session.execute(
                    update(Revision).where(Revision.id == revision).values(analyzed_at=at)
                )
                made += [len(commit_status(session, revision))]
                session.commit()
                if send_each:
                    deliver_due(database_url, api.settings)
        return made

    # sent as they come: success, pending, success again, each change once
    assert judged_again("r6", [True, True, False, False, True, True], True) == [1, 0, 1, 0, 1, 0]
    said = [json.loads(call.body)["state"] for call in receiver.requests]
    assert said == ["success", "pending", "success"]
    # made faster than sent (one delivery run after all three): only the last one goes out
    receiver.requests.clear()
    assert judged_again("r5", [True, False, True], False) == [1, 1, 1]
    deliver_due(database_url, api.settings)
    said = [json.loads(call.body)["state"] for call in receiver.requests]
    assert said == ["success"]
    with session_factory(database_url)() as session:
        states = session.scalars(
            select(Delivery.state).where(Delivery.key.startswith("status:5:")).order_by(Delivery.id)
        ).all()
    assert states == ["superseded", "superseded", "delivered"]


def test_two_scans_of_one_revision_at_once_take_turns_and_tell_its_state_once(
    api, tmp_path, receiver
):
    """Two scans of r6 at once (a walk's and an ingestion's): the second waits for the first
    to commit, then sees the status told and makes none. Without the turn both read no status
    told, pick the same key, and the second fails on it (or, had the verdicts differed, the one
    that read the older could land last)."""
    _target(api, receiver)
    revisions(api, tmp_path, [10.0] * 6)
    database_url = api.settings.database_url
    make = session_factory(database_url)
    with make() as session:
        session.execute(update(Revision).values(commit="d" * 40))
        session.commit()
        r6 = session.scalar(select(Revision.id).where(Revision.title == "r6"))
    outcome: dict[str, object] = {}

    def second_scan() -> None:
        try:
            with make() as other:
                outcome["made"] = commit_status(other, r6)
                other.commit()
        except Exception as exc:  # noqa: BLE001 - the test reports it
            outcome["error"] = exc

    with make() as first:
        assert len(commit_status(first, r6)) == 1  # made, not committed yet
        thread = threading.Thread(target=second_scan)
        thread.start()
        thread.join(1.0)
        assert thread.is_alive(), "the second scan did not wait for the first"
        first.commit()
    thread.join(30)
    assert not thread.is_alive()
    assert outcome == {"made": []}, outcome
    with make() as session:
        keys = session.scalars(
            select(Delivery.key).where(Delivery.key.startswith(f"status:{r6}:"))
        ).all()
    assert keys == [f"status:{r6}:success"]
    deliver_due(database_url, api.settings)
    assert [json.loads(c.body)["state"] for c in receiver.requests] == ["success"]


def test_a_status_waits_while_an_older_one_of_its_revision_is_being_sent(api, tmp_path, receiver):
    """Two statuses of one commit sent at once may land in either order: a newer one is not
    sent while an older one is leased for sending (another worker's), and goes once that ends."""
    _target(api, receiver)
    revisions(api, tmp_path, [10.0] * 6)
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        session.execute(update(Revision).values(commit="e" * 40))
        r6 = session.scalar(select(Revision.id).where(Revision.title == "r6"))
        (older,) = commit_status(session, r6)
        in_an_hour = utcnow() + timedelta(hours=1)
        session.execute(
            update(Delivery)
            .where(Delivery.id == older)
            .values(state="sending", lease_until=in_an_hour)
        )
        session.execute(update(Revision).where(Revision.id == r6).values(analyzed_at=None))
        (newer,) = commit_status(session, r6)  # pending: judged again
        session.commit()
    deliver_due(database_url, api.settings)
    assert receiver.requests == []  # held back while the older one is on its way
    with session_factory(database_url)() as session:
        assert session.get_one(Delivery, newer).state == "pending"
        session.execute(
            update(Delivery).where(Delivery.id == older).values(state="delivered", lease_until=None)
        )
        session.commit()
    deliver_due(database_url, api.settings)
    assert [json.loads(c.body)["state"] for c in receiver.requests] == ["pending"]


def test_a_commit_that_is_no_hash_gets_no_status_nor_any_other_address(api, tmp_path, receiver):
    """A security review: a ci token's revision of commit "abc1234/../../../hijacked/path" made
    the worker POST its status, with the admin's forge token, to /hijacked/path (httpx folds
    the dot segments). Forges address statuses by hash: only a hash gets one, as one segment."""
    _target(api, receiver)
    revisions(api, tmp_path, [10.0] * 6)
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        r5, r6 = session.scalars(select(Revision).where(Revision.title.in_(["r5", "r6"]))).all()
        r5.commit, r6.commit = "abc1234/../../../../../../hijacked/path", "v1.2"
        session.commit()
        assert commit_status(session, r5.id) == [] and commit_status(session, r6.id) == []
        forged = Delivery(
            uid="forged",
            key="status:forged",
            component_id=r5.component_id,
            kind="status",
            event="status.success",
            payload={"sha": r5.commit, "state": "success", "description": "d",
                     "context": "redline/builder", "page": "/"},
        )  # fmt: skip
        session.add(forged)  # as if queued by an earlier version
        session.commit()
    deliver_due(database_url, api.settings)
    assert not [call for call in receiver.requests if "hijacked" in call.path], receiver.requests
    with session_factory(database_url)() as session:
        sent = session.scalars(select(Delivery).where(Delivery.uid == "forged")).one()
        assert sent.state == "failed" and "not a commit hash" in sent.last_error, sent.last_error
