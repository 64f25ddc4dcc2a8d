"""What an improvement's alert links to (`redline.worker.messages`): it has no regression page,
and a trial's webhook for one named the revision by title alone, with a link only to a chart."""

from __future__ import annotations

import json
from datetime import UTC, datetime

from redline.server.models import Detection, Revision, Series
from redline.worker import messages

PUBLIC = "https://redline.example"


def _improvement() -> dict:
    series = Series(case="reads", phase="steady", params=json.dumps({"rate": 40}),
                    process="kv store", counter="cpu_percent")  # fmt: skip
    found = Detection(method="execution_shift", effect=-0.31, p_value=None, direction="decrease",
                      confirmation="")  # fmt: skip
    revision = Revision(title="fast path", commit="ab12")
    change = messages.change_body("kv store", found, series, revision, "r6")
    return messages.alert_body("kv store", "improvement", None, [change])


def test_an_improvement_links_its_revision_s_page_in_every_channel() -> None:
    body = _improvement()
    page = f"{PUBLIC}/components/kv%20store/revisions/fast%20path"
    hook = messages.webhook_json("improvement", "d1", body, PUBLIC, datetime.now(UTC))
    revision = hook["alerts"][0]["changes"][0]["revision"]
    assert (revision["title"], revision["page_url"]) == ("fast path", page)
    assert f"<{page}|" in messages.slack_json("improvement", body, PUBLIC)["text"]
    _, text, html = messages.email("improvement", body, PUBLIC)
    assert f"Revision: {page}" in text and f'href="{page}"' in html


def test_a_ci_failure_leads_with_the_largest_change_for_the_worse_as_the_alert_does() -> None:
    """A trial's JUnit failure led with the driver's round trip (+21 %) where the alert for
    the same revision led with the larger CPU change (+64 %)."""
    from redline.server.schemas.alerts import CaseVerdict, CiVerdict
    from redline.server.services.ci_junit import junit_xml
    from redline.server.services.ci_verdict import _worst_first

    def change(counter: str, effect: float | None, worse: bool = True) -> dict:
        return {"process": "builder", "counter": counter, "method": "execution_shift",
                "effect": effect, "p_value": None, "direction": "increase", "worse": worse,
                "confirmation": "suspected", "confirmation_reason": ""}  # fmt: skip

    found = [change("rtt_p90_us", 0.21), change("threads", -0.5, worse=False),
             change("cpu_percent", 0.64), change("timeouts", None)]  # fmt: skip
    ordered = sorted(found, key=_worst_first)
    assert [c["counter"] for c in ordered] == ["timeouts", "cpu_percent", "rtt_p90_us", "threads"]
    case = CaseVerdict(case="locate", phase="steady", parameters={}, state="failed",
                       changes=ordered[1:])  # fmt: skip
    verdict = CiVerdict(component="builder", revision="r6", state="done", regressions=2,
                        improvements=1, skipped=0, cases=[case], page="/")  # fmt: skip
    assert 'message="regression: builder cpu_percent +64.0 %' in junit_xml(verdict)
    body = messages.alert_body("builder", "regression", None, [
        {**c, "parameters": {}, "revision": {"title": "r6"}} for c in (found[0], found[2])
    ])  # fmt: skip
    assert body["summary"].startswith("builder: regression: cpu_percent +64.0 %")
