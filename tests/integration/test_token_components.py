"""Tokens bound to components (security.md): a ci token reported revisions of any component, a
triage token triaged any component's regressions, an agent token ran any component's jobs its
labels allowed and reported run-time alerts for any component. An admin may now bind each to
components; bound, it acts on those only (403 naming them), in the API and on the pages."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from redline.server.db import session_factory
from redline.server.models import Component, Job, JobState, Revision
from redline.server.services.tokens import issue_token
from sqlalchemy import select

from tests.support.api import HOST, LABELS, Api, api_with
from tests.support.history import regression_between
from tests.support.pages import form_token, sign_in
from tests.support.servers import Services


@pytest.fixture
def api(services: Services, tmp_path: Path) -> Iterator[Api]:
    with api_with(services, tmp_path) as api:
        api.component("builder")
        api.component("planner")
        yield api


def _bound(api: Api, name: str, scope: str, components: str, host: str | None = None) -> dict:
    with session_factory(api.settings.database_url)() as session:
        labels = LABELS if host else ()
        secret = issue_token(session, name, scope, host, labels, components)[1]
    return {"Authorization": f"Bearer {secret}"}


def test_an_admin_binds_a_token_to_components_that_exist(api: Api):
    admin = api.tokens["admin"]
    made = api.client.post(
        "/api/v1/tokens",
        headers=admin,
        json={"name": "gitlab-b", "scopes": ["ci"], "components": ["builder"]},
    )
    assert made.status_code == 201 and made.json()["components"] == ["builder"], made.text
    listed = {t["name"]: t for t in api.client.get("/api/v1/tokens", headers=admin).json()}
    assert listed["gitlab-b"]["components"] == ["builder"] and listed["ci"]["components"] == []
    for body, said in (
        ({"scopes": ["ci"], "components": ["buidler"]}, "unknown component 'buidler'"),
        ({"scopes": ["admin"], "components": ["builder"]}, "reads or administers every"),
        ({"scopes": ["read"], "components": ["builder"]}, "reads or administers every"),
    ):
        refused = api.client.post("/api/v1/tokens", headers=admin, json={"name": "x", **body})
        assert refused.status_code == 400 and said in refused.json()["detail"], refused.text


def test_a_bound_ci_token_reports_and_cancels_its_components_revisions_only(api: Api):
    ci = _bound(api, "gitlab-b", "ci", "builder")

    def report(component: str) -> object:
        body = {"component": component, "title": "r1", "sort_key": "1", "commit": "abc1234"}
        return api.client.post("/api/v1/revisions", json=body, headers=ci)

    assert report("builder").status_code == 201
    refused = report("planner")
    assert refused.status_code == 403, refused.text
    assert refused.json()["detail"] == (
        "token 'gitlab-b' acts on the components builder only, not 'planner'"
    )
    api.revision("r1", "1", component="planner")  # an unbound ci token reports any
    cancel = "/api/v1/components/{}/revisions/r1/cancel"
    assert api.client.post(cancel.format("planner"), headers=ci).status_code == 403
    assert api.client.post(cancel.format("builder"), headers=ci).status_code == 200
    results = {"component": "planner", "revision": "r2", "sort_key": "2",
               "results": [{"case": "c", "counter": "x", "values": [1.0]}]}  # fmt: skip
    imported = api.client.post("/api/v1/import/results", json=results, headers=ci)
    assert imported.status_code == 403 and "not 'planner'" in imported.text
    lnt = api.client.post("/api/v1/import/lnt?component=planner", content=b"{}", headers=ci)
    assert lnt.status_code == 403 and "not 'planner'" in lnt.text


def _regression(api: Api, component: str) -> int:
    with session_factory(api.settings.database_url)() as session:
        owner = session.scalars(select(Component).where(Component.name == component)).one()
        revision = session.scalars(select(Revision).where(Revision.component_id == owner.id))
        only = revision.one()
        regression = regression_between(session, only, only)
        session.commit()
        return regression.id


def test_a_bound_triage_token_triages_its_components_regressions_only(api: Api):
    for component in ("builder", "planner"):
        api.revision("r1", "1", component=component)
    mine, theirs = _regression(api, "builder"), _regression(api, "planner")
    triage = _bound(api, "team-b", "triage", "builder")
    change = {"state": "acknowledged", "comment": "ours"}
    path = "/api/v1/components/{}/regressions/{}"
    refused = api.client.patch(path.format("planner", theirs), json=change, headers=triage)
    assert refused.status_code == 403 and "not 'planner'" in refused.text, refused.text
    done = api.client.patch(path.format("builder", mine), json=change, headers=triage)
    assert done.status_code == 200 and done.json()["state"] == "acknowledged", done.text
    # on the pages, a session opened with the token is bound as the token is
    client = api.client
    sign_in(client, {"token": triage["Authorization"].removeprefix("Bearer ")})
    shown = client.get(f"/regressions/{theirs}").text
    assert 'id="triage"' not in shown and "triages the regressions of builder only" in shown
    assert 'id="triage"' in client.get(f"/regressions/{mine}").text  # its own: offered
    csrf = form_token(shown)
    form = {"csrf": csrf, "state": "acknowledged", "comment": "not ours"}
    page = client.post(f"/regressions/{theirs}/triage", data=form)
    assert page.status_code == 403 and "not &#39;planner&#39;" in page.text, page.text[-500:]
    detail = api.client.get(path.format("planner", theirs)).json()
    assert detail["state"] != "acknowledged"  # nothing changed


def test_a_bound_agent_token_runs_and_reports_alerts_of_its_components_only(api: Api):
    agent = _bound(api, f"agent-{HOST}-b", "agent", "builder", host=HOST)
    register = {"name": HOST, "labels": []}
    assert api.client.post("/api/v1/agent/register", json=register, headers=agent).is_success
    planner = api.revision("r1", "1", component="planner")["job_ids"]
    builder = api.revision("r1", "1", component="builder")["job_ids"]
    leased = api.client.post("/api/v1/agent/lease", json={"host": HOST}, headers=agent)
    assert leased.status_code == 200 and leased.json()["id"] in builder, leased.text
    nothing = api.client.post("/api/v1/agent/lease", json={"host": HOST}, headers=agent)
    assert nothing.status_code == 204, nothing.text  # never given planner's job
    held = api.lease()["id"]  # an unbound token of the same host is
    assert held in planner
    # nor may it touch that job as the host both tokens act for (a reviewer's find)
    for action, body in (("heartbeat", {}), ("release", {}), ("fail", {"reason": "no"})):
        touched = api.client.post(
            f"/api/v1/jobs/{held}/{action}", json={"host": HOST, **body}, headers=agent
        )
        assert touched.status_code == 403 and "not 'planner'" in touched.text, touched.text
    upload = {**agent, "X-Redline-Host": HOST, "X-Redline-Sha256": "0" * 64}
    refused = api.client.put(f"/api/v1/jobs/{held}/recording", content=b"x", headers=upload)
    assert refused.status_code == 403 and "not 'planner'" in refused.text, refused.text
    with session_factory(api.settings.database_url)() as session:
        assert session.get_one(Job, held).state == JobState.leased  # untouched
    alert = {"target": "cpu_percent", "started": True, "residual": 9.0, "threshold": 4.0}
    theirs = api.client.post("/api/v1/components/planner/runtime-alerts", json=alert, headers=agent)
    assert theirs.status_code == 403 and "not 'planner'" in theirs.text, theirs.text
    ours = api.client.post("/api/v1/components/builder/runtime-alerts", json=alert, headers=agent)
    assert ours.status_code == 201, ours.text


def test_deleting_a_component_unbinds_its_tokens_and_widens_none(api: Api):
    """A reviewer's find: a token bound to a deleted component would act on a component made
    later under its name, and one bound to it alone, left bound to none, on every component."""
    alone = _bound(api, "team-b", "ci", "builder")
    _bound(api, "team-bp", "triage", "builder,planner")
    deleted = api.client.delete("/api/v1/components/builder", headers=api.tokens["admin"])
    assert deleted.status_code == 200 and deleted.json()["tokens_revoked"] == 1, deleted.text
    listed = {
        t["name"]: t for t in api.client.get("/api/v1/tokens", headers=api.tokens["admin"]).json()
    }
    assert listed["team-b"]["revoked"] and listed["team-b"]["components"] == []
    assert not listed["team-bp"]["revoked"] and listed["team-bp"]["components"] == ["planner"]
    api.component("builder")  # made again under the name
    body = {"component": "builder", "title": "r1", "sort_key": "1", "commit": "abc1234"}
    assert api.client.post("/api/v1/revisions", json=body, headers=alone).status_code == 401
