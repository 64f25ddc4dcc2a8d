"""Alert subscriptions on the settings pages, through the real app on real Postgres: a component's
changed in place (a new secret replaces the old one and is never shown), and the subscriptions
to every component's listed, made, changed and deleted on /settings. Every form carries the
session's form token, and a post without it changes nothing."""

from __future__ import annotations

import re
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from redline.server.app import create_app
from redline.server.core.config import Settings
from redline.server.db import session_factory
from redline.server.models import Delivery, Subscription
from redline.server.services.signin import create_user
from sqlalchemy import select

from tests.support.api import emptied_with_tokens
from tests.support.pages import form_token, history, sign_in
from tests.support.servers import Services

PAGE = "/settings/components/builder"


@pytest.fixture
def client(services: Services, database_url: str, tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(
        database_url=database_url,
        redis_url=services.redis_url,
        storage_dir=tmp_path / "storage",
        queue=f"test-{uuid.uuid4().hex[:8]}",
    )
    emptied_with_tokens(database_url)
    history(database_url, tmp_path, [20.0])
    with session_factory(database_url)() as session:
        create_user(session, "root", "correct horse battery", "admin")
        create_user(session, "ada", "correct horse battery", "ci")
    with TestClient(create_app(settings)) as client:
        sign_in(client, {"name": "root", "password": "correct horse battery"})
        yield client


def _stored(client: TestClient) -> list[Subscription]:
    with session_factory(client.app.state.settings.database_url)() as session:
        return list(session.scalars(select(Subscription).order_by(Subscription.id)))


def _every_form_has_the_token(page: str) -> str:
    csrf = form_token(page)
    forms = re.findall(r'<form method="post".*?</form>', page, re.S)
    assert forms and all(f'name="csrf" value="{csrf}"' in form for form in forms)
    return csrf


def test_a_components_subscription_is_changed_in_place_and_its_secret_never_shown(client):
    csrf = _every_form_has_the_token(client.get(PAGE).text)
    made = client.post(
        f"{PAGE}/subscriptions",
        data={
            "csrf": csrf,
            "kind": "webhook",
            "url": "https://hooks.example/a",
            "secret": "first-secret",
            "confirmed_only": "1",
        },
        follow_redirects=False,
    )
    assert made.status_code == 303, made.text
    (hook,) = _stored(client)
    page = client.get(PAGE).text
    assert f'action="{PAGE}/subscriptions/{hook.id}"' in page  # an edit form per subscription
    assert "first-secret" not in page and "(signed)" in page
    _every_form_has_the_token(page)
    edit = f"{PAGE}/subscriptions/{hook.id}"
    change = {"url": "https://hooks.example/b", "secret": "second-secret", "format": "slack",
              "counters": "rtt_p90, cpu", "direction": "improvement", "min_effect": "12.5",
              "delivery": "digest"}  # fmt: skip  # confirmed_only unticked
    assert client.post(edit, data=change).status_code == 403  # no form token
    assert client.post(edit, data={**change, "csrf": "forged"}).status_code == 403
    assert _stored(client)[0].url == "https://hooks.example/a"  # unchanged
    done = client.post(edit, data={**change, "csrf": csrf}, follow_redirects=False)
    assert done.status_code == 303 and done.headers["location"] == f"{PAGE}#alerts"
    (hook,) = _stored(client)
    assert (hook.url, hook.secret, hook.format, hook.counters, hook.direction) == (
        "https://hooks.example/b", "second-secret", "slack", ["rtt_p90", "cpu"], "improvement"
    )  # fmt: skip
    assert (hook.min_effect, hook.confirmed_only, hook.delivery) == (0.125, False, "digest")
    page = client.get(PAGE).text
    assert "second-secret" not in page and "first-secret" not in page
    assert "improvement of rtt_p90, cpu, at least 12.5 %, when flagged" in page
    # saved again without a secret: it keeps the one it has; removed only when asked
    kept = {"csrf": csrf, "url": "https://hooks.example/b", "format": "slack"}
    assert client.post(edit, data=kept, follow_redirects=False).status_code == 303
    assert _stored(client)[0].secret == "second-secret"
    assert client.post(edit, data={**kept, "clear_secret": "1"}).status_code == 200
    assert _stored(client)[0].secret == ""
    # refused, naming the field, and nothing stored: a url that is none, an email's field
    bad = client.post(edit, data={**kept, "url": "ftp://x.example", "secret": "third-secret"})
    assert bad.status_code == 400 and "url:" in bad.text and "http:// or https://" in bad.text
    assert "third-secret" not in bad.text
    other = client.post(edit, data={**kept, "address": "a@robots.example"})
    assert other.status_code == 422 and "takes none" in other.text
    assert (_stored(client)[0].url, _stored(client)[0].address) == ("https://hooks.example/b", "")


def test_subscriptions_to_every_component_are_listed_made_changed_and_deleted_on_settings(
    client,
):
    page = client.get("/settings").text
    assert 'id="server-subscriptions"' in page and "No one is subscribed yet." in page
    csrf = _every_form_has_the_token(page)
    assert client.post("/settings/subscriptions", data={"kind": "email"}).status_code == 403
    made = client.post(
        "/settings/subscriptions",
        data={"csrf": csrf, "kind": "email", "address": "all@robots.example", "min_effect": "5"},
        follow_redirects=False,
    )
    assert made.status_code == 303 and made.headers["location"] == "/settings#alerts"
    (everywhere,) = _stored(client)
    assert everywhere.component_id is None and everywhere.min_effect == 0.05
    page = client.get("/settings").text
    assert "email: all@robots.example" in page
    assert "all@robots.example" not in client.get(PAGE).text  # not the component's own
    _every_form_has_the_token(page)
    # its last messages, newest first, three at most
    with session_factory(client.app.state.settings.database_url)() as session:
        for n in range(4):
            session.add(
                Delivery(
                    uid=str(uuid.uuid4()),
                    subscription_id=everywhere.id,
                    kind="email",
                    event=f"event-{n}",
                    payload={},
                    state="failed",
                    attempts=5,
                    last_error=f"SMTP: refused {n}",
                )  # fmt: skip
            )
        session.commit()
    page = client.get("/settings").text
    assert "event-3: failed after 5 tries (SMTP: refused 3)" in page
    assert page.index("event-3") < page.index("event-2") < page.index("event-1")
    assert "event-0" not in page
    edit = f"/settings/subscriptions/{everywhere.id}"
    changed = client.post(
        edit,
        data={
            "csrf": csrf,
            "address": "leads@robots.example",
            "delivery": "digest",
            "direction": "any",
            "confirmed_only": "1",
        },
        follow_redirects=False,
    )
    assert changed.status_code == 303, changed.text
    (everywhere,) = _stored(client)
    assert (everywhere.address, everywhere.delivery, everywhere.direction) == (
        "leads@robots.example", "digest", "any"
    )  # fmt: skip
    # a component's subscription is not one of these, and an unknown one is named
    client.post(f"{PAGE}/subscriptions", data={"csrf": csrf, "kind": "email",
                                               "address": "b@robots.example"})  # fmt: skip
    own = next(s for s in _stored(client) if s.component_id is not None)
    wrong = client.post(
        f"/settings/subscriptions/{own.id}", data={"csrf": csrf, "address": "x@y.z"}
    )
    assert wrong.status_code == 404 and f"the server has no subscription {own.id}" in wrong.text
    gone = client.post(f"{edit}/delete", data={"csrf": csrf}, follow_redirects=False)
    assert gone.status_code == 303
    assert [s.id for s in _stored(client)] == [own.id]
    assert "No one is subscribed yet." in client.get("/settings").text


def test_only_an_administrator_changes_subscriptions_on_the_pages(client):
    csrf = form_token(client.get("/settings").text)
    client.post("/settings/subscriptions", data={"csrf": csrf, "kind": "email",
                                                 "address": "all@robots.example"})  # fmt: skip
    (everywhere,) = _stored(client)
    client.post("/signout", data={"csrf": csrf})
    sign_in(client, {"name": "ada", "password": "correct horse battery"})
    token = form_token(client.get("/").text)
    for path in (f"/settings/subscriptions/{everywhere.id}", "/settings/subscriptions"):
        refused = client.post(
            path, data={"csrf": token, "kind": "email", "address": "eve@robots.example"}
        )
        assert refused.status_code == 403 and "admin" in refused.text
    refused = client.post(f"/settings/subscriptions/{everywhere.id}/delete", data={"csrf": token})
    assert refused.status_code == 403
    assert [(s.id, s.address) for s in _stored(client)] == [(everywhere.id, "all@robots.example")]
