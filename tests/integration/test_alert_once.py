"""Once per regression per subscription (issue 14), where the regression changes under the alert:
a triage to false positive, and a re-analysis that moves the flagged change to a revision
reported late. Real Postgres, the real detectors and a real HTTP receiver."""

from __future__ import annotations

import json

from redline.server.db import session_factory
from redline.server.models import Detection, RegressionState, Revision
from redline.server.schemas.regressions import TriageRequest
from redline.server.services.regressions import triage
from redline.worker.reanalysis import reanalyze_component
from sqlalchemy import distinct, func, select

from tests.support import alerting
from tests.support.alerting import (
    a_period_later,
    alert,
    cpu_and_rss,
    eager,
    grow_by_rss,
    revisions,
    subscribe,
)
from tests.support.api import Api

api, mailbox, receiver = alerting.api, alerting.mailbox, alerting.receiver  # the fixtures


def _flagged_at(api: Api) -> list[str]:
    """The revisions with a flagged detection, in order."""
    with session_factory(api.settings.database_url)() as session:
        return list(
            session.scalars(
                select(Revision.title)
                .where(Revision.id.in_(select(Detection.revision_id).where(Detection.flagged)))
                .order_by(Revision.order_key)
            )
        )


def test_a_regression_triaged_as_false_positive_is_not_told_again_when_it_grows(
    api, tmp_path, receiver
):
    subscribe(api, eager(receiver, "/hook"))
    cpu_and_rss(api, tmp_path)
    alert(api)
    (first,) = receiver.requests
    told = json.loads(first.body)["alerts"][0]["regression"]
    with session_factory(api.settings.database_url)() as session:
        state = TriageRequest(state=RegressionState.false_positive, comment="a noisy host")
        triage(session, "builder", told["id"], state, "ada")
    alert(api)
    assert len(receiver.requests) == 1  # the triage itself sends nothing
    # it grows by a series, a period later: what a regression not triaged is told again for
    # (test_a_growing_regression_is_updated_once_a_period_with_its_new_series_only)
    grow_by_rss(api)
    a_period_later(api)
    alert(api)
    alert(api)
    assert len(receiver.requests) == 1
    detail = api.client.get(f"/api/v1/components/builder/regressions/{told['id']}").json()
    assert detail["state"] == "false_positive"  # the same regression, still triaged
    with session_factory(api.settings.database_url)() as session:
        grown = session.scalar(
            select(func.count(distinct(Detection.series_id))).where(
                Detection.regression_id == told["id"], Detection.flagged
            )
        )
    assert grown == 2  # cpu and rss: it did grow, and was not told


def test_a_change_moved_by_reanalysis_to_a_revision_reported_late_is_not_told_again(
    api, tmp_path, receiver
):
    """r6 is reported after r7 and r8 (CI ran out of order): the step found at r7 is at r6 once
    the history is analysed again. It is the change the subscription was told about, not a new
    one, nor a growth of its regression a period later."""
    hook = subscribe(api, eager(receiver, "/hook"))
    revisions(api, tmp_path, [10.0] * 5)
    revisions(api, tmp_path, [14.0, 14.0], first=7)
    alert(api)
    (first,) = receiver.requests
    (told,) = json.loads(first.body)["alerts"][0]["changes"]
    assert told["revision"]["title"] == "r7"
    revisions(api, tmp_path, [14.0], first=6)  # reported late, between r5 and r7
    reanalyze_component(api.settings.database_url, 1)
    assert _flagged_at(api) == ["r6"]  # the change moved
    alert(api)
    a_period_later(api)
    alert(api)
    # what it hears since is how the regression it was told settled, not the change again
    later = [json.loads(r.body) for r in receiver.requests[1:]]
    assert [body["event"] for body in later] == ["regression.confirmed"], later
    assert (
        later[0]["alerts"][0]["regression"]["id"]
        == json.loads(first.body)["alerts"][0]["regression"]["id"]
    )
    log = api.client.get(
        f"/api/v1/components/builder/subscriptions/{hook['id']}/deliveries",
        headers=api.tokens["admin"],
    ).json()
    assert [d["event"] for d in log] == ["regression.confirmed", "regression"]
