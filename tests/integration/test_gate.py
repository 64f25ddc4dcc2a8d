"""The CI gate on a revision's page, on real Postgres: a failing gate links the regressions of
the changes it fails on, and no other regression its revision has a detection in."""

from __future__ import annotations

from redline.detect.config import CHARTED_METHOD
from redline.detect.confirmation import DROPPED
from redline.server.models import Detection, Regression, Series
from redline.server.services.gate import gate
from sqlalchemy import select

from tests.support.history import COMPONENT, cpu_history, ingest_and_detect


def test_a_failing_gate_links_only_the_regressions_of_the_changes_it_fails_on(
    session, database_url, tmp_path
) -> None:
    """The page linked every regression with a detection in the revision: a dropped spike's
    and a charting method's beside the verdict's own, which counted neither."""
    ingest_and_detect(database_url, cpu_history(session, tmp_path, [10.0] * 6 + [30.0]))
    failing = session.scalars(select(Detection).where(Detection.regression_id.is_not(None))).one()
    revision = failing.revision
    memory = Series(
        component_id=failing.series.component_id,
        case=failing.series.case,
        phase=failing.series.phase,
        params=failing.series.params,
        process=failing.series.process,
        counter="rss",
    )
    session.add(memory)
    session.flush()
    charted = session.scalars(  # flagged too, with no regression of its own
        select(Detection).where(
            Detection.revision_id == revision.id, Detection.method == CHARTED_METHOD
        )
    ).one()
    assert charted.flagged and charted.regression_id is None
    spike = Detection(  # a spike the later revisions dropped
        series_id=memory.id,
        revision_id=revision.id,
        baseline_revision_id=failing.baseline_revision_id,
        method=failing.method,
        verdict="change",
        flagged=True,
        direction="increase",
        confirmation=DROPPED,
    )
    session.add(spike)
    others = []
    for detection in (spike, charted):  # as if each had been grouped into one of its own
        regression = Regression(
            component_id=memory.component_id,
            good_revision_id=failing.baseline_revision_id,
            bad_revision_id=revision.id,
            good_key="6",
            bad_key="7",
            confirmation="not_confirmed",
        )
        session.add(regression)
        session.flush()
        detection.regression_id = regression.id
        others.append(regression.id)
    session.commit()
    said = gate(session, COMPONENT, revision.title)
    assert said.state == "failed"
    assert [regression[0] for regression in said.regressions] == [failing.regression_id]
    assert failing.regression_id not in others
