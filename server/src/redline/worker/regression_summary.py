"""A regression's confirmation in words: confirmed when one of its changes held, not confirmed
when every one was dropped, suspected until then, quoting the reason of the largest of its
changes in that state and its largest change, each naming its series
(`redline.worker.confirmation` settles the changes).
"""

from __future__ import annotations

from collections import defaultdict

from redline.detect.confirmation import DROPPED, HELD, SUSPECTED
from redline.server.models import Detection, Regression, Series
from redline.server.services.open_regressions import largest_changes, series_label
from sqlalchemy import func, select
from sqlalchemy.dialects.postgresql import distinct_on
from sqlalchemy.orm import Session

CONFIRMED, NOT_CONFIRMED = "confirmed", "not_confirmed"


def _largest_reasons(session: Session, component_id: int) -> dict[tuple[int, str], str]:
    """Per (regression, state) of the component's detections, the largest one's reason (one
    from zero, with no ratio, after the rest, as `largest_changes` leaves it out), naming its
    series: what a regression's summary quotes (one query for the component, not one per
    regression on every revision stored). A trial's summary quoted one parameter set's pairs
    beside another's largest change, neither named; a fifth trial's named both, the newest
    set's pairs beside the largest set's +79 %."""
    rows = session.execute(
        select(Detection.regression_id, Detection.confirmation, Detection.confirmation_reason)
        .add_columns(Series.case, Series.phase, Series.process, Series.counter, Series.params)
        .join(Regression, Regression.id == Detection.regression_id)
        .join(Series, Series.id == Detection.series_id)
        .where(
            Regression.component_id == component_id,
            Detection.confirmation.in_((HELD, SUSPECTED, DROPPED)),
        )
        .ext(distinct_on(Detection.regression_id, Detection.confirmation))
        .order_by(
            Detection.regression_id,
            Detection.confirmation,
            func.abs(Detection.effect).desc().nulls_last(),  # as `largest_changes` ranks them
            Detection.id,
        )
    )
    return {
        (rid, state): f"{series_label(case, phase, process, counter, params)}: {reason}"
        for rid, state, reason, case, phase, process, counter, params in rows
        if rid is not None
    }


def summarize_regressions(session: Session, component_id: int) -> None:
    """Each regression of the component: confirmed, not confirmed or suspected, and why."""
    states: dict[int, dict[str, int]] = defaultdict(dict)
    for regression_id, state, number in session.execute(
        select(Detection.regression_id, Detection.confirmation, func.count())
        .join(Regression, Regression.id == Detection.regression_id)
        .where(Regression.component_id == component_id)
        .group_by(Detection.regression_id, Detection.confirmation)
    ):
        if regression_id is not None:  # joined to a regression: typed as nullable all the same
            states[regression_id][state] = number
    reasons = _largest_reasons(session, component_id)
    largest = largest_changes(session, component_id)
    for regression in session.scalars(
        select(Regression).where(Regression.component_id == component_id)
    ):
        counts = states.get(regression.id, {})
        total = sum(counts.values())
        if not total:
            continue  # withdrawn (`redline.worker.grouping`): it says what it had been
        held, dropped = counts.get(HELD, 0), counts.get(DROPPED, 0)
        if held:
            confirmation = CONFIRMED
            # what confirmed it, pairs or the later revisions (a trial's regression confirmed
            # by pairs was said to have held over later revisions that did not exist)
            example = reasons.get((regression.id, HELD))
            reason = f"{held} of {total} flagged change(s) confirmed ({example})"
        elif total and dropped == total:
            confirmation = NOT_CONFIRMED
            example = reasons.get((regression.id, DROPPED))
            reason = f"none of the {total} flagged change(s) held: {example}"
        else:
            confirmation = SUSPECTED
            example = reasons.get((regression.id, SUSPECTED))
            reason = f"{total - dropped} flagged change(s) still suspected: {example}"
        if regression.id in largest:
            reason += f"; the largest: {largest[regression.id]}"
        if (regression.confirmation, regression.confirmation_reason) != (confirmation, reason):
            regression.confirmation, regression.confirmation_reason = confirmation, reason
