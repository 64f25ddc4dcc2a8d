"""Grouping flagged detections into regressions: same component, overlapping revision ranges.
Each grouped detection starts suspected, until the later revisions confirm it or not
(`redline.worker.confirmation`).

Only a change for the worse is a regression (`redline.detect.counters.worse`: a CPU or round
trip that rose, an achieved rate that fell); a flagged improvement stays a detection. A flagged
detection spans (newest baseline revision, its revision]; it joins the oldest
regression of the component whose range overlaps that span (widening the range), else it opens
a new one. A regression left without detections when its revisions are judged again is
withdrawn (`_withdraw_emptied`): kept with what it had been, never deleted once anyone could see
it; a triaged one keeps its label too, because its label is ground truth.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Collection

from redline.detect.confirmation import SUSPECTED
from redline.detect.counters import worse
from redline.server.models import (
    WITHDRAWN,
    Detection,
    Regression,
    RegressionEvent,
    RegressionState,
    Revision,
    Series,
    utcnow,
)
from sqlalchemy import delete, exists, select, tuple_
from sqlalchemy.orm import Session, aliased


def _span(
    session: Session, detection: Detection, revision: Revision
) -> tuple[Revision, Revision] | None:
    if detection.baseline_revision_id is None:
        return None
    return session.get_one(Revision, detection.baseline_revision_id), revision


def _overlapping(
    session: Session, component_id: int, good: Revision, bad: Revision
) -> Regression | None:
    """The oldest regression whose (good, bad] range overlaps this one. Revisions are ordered
    by (sort key, id), as everywhere: two with one sort key (commits of one second, keyed by
    their time) span a range that their keys alone make empty, which overlapped nothing and
    opened a regression per flagged series."""
    return session.scalar(
        select(Regression)
        .where(
            Regression.component_id == component_id,
            # a withdrawn one keeps its old range: a change joining it would be split from the
            # live regression beside it, and a re-analysis would merge what it finds apart
            Regression.confirmation != WITHDRAWN,
            tuple_(Regression.good_key, Regression.good_revision_id) < bad.place,
            tuple_(Regression.bad_key, Regression.bad_revision_id) > good.place,
        )
        .order_by(Regression.id)
        .limit(1)
    )


def _widen(regression: Regression, good: Revision, bad: Revision) -> None:
    if good.place < (regression.good_key, regression.good_revision_id):
        regression.good_revision_id, regression.good_key = good.id, good.order_key
    if bad.place > (regression.bad_key, regression.bad_revision_id):
        regression.bad_revision_id, regression.bad_key = bad.id, bad.order_key


def _withdraw_emptied(session: Session, component_id: int) -> None:
    """The component's regressions left without a detection. One never summarized (its
    confirmation reason empty: made and emptied within one analysis, as a change found a
    revision late moves to its revision) and untriaged is deleted: no one could have seen it.
    Any other is withdrawn, its reason saying when and what it had been (its confirmation and
    the figures its summary quoted): an alert's link to it still leads to it. A change found
    again later opens a regression of its own (`_overlapping` skips withdrawn ones)."""
    has_detection = exists().where(Detection.regression_id == Regression.id)
    has_event = exists().where(RegressionEvent.regression_id == Regression.id)
    emptied = (Regression.component_id == component_id, ~has_detection)
    session.execute(
        delete(Regression)
        .where(
            *emptied,
            Regression.state == RegressionState.new,
            Regression.confirmation_reason == "",
            ~has_event,
        )
        .execution_options(synchronize_session=False)
    )
    now = utcnow()
    for regression in session.scalars(
        select(Regression).where(*emptied, Regression.confirmation != WITHDRAWN)
    ):
        had = regression.confirmation + (
            f": {regression.confirmation_reason}" if regression.confirmation_reason else ""
        )
        regression.confirmation, regression.confirmation_reason = (
            WITHDRAWN,
            (
                f"withdrawn {now:%Y-%m-%d %H:%M} UTC: its revisions were judged again and none of "
                f"its changes is found any more; it had been {had}"
            ),
        )


def group_revision(session: Session, revision: Revision, alarming: Collection[str]) -> None:
    """Attach the revision's flagged detections of the ``alarming`` methods to regressions;
    withdraw emptied ones.

    The caller holds the component's row lock (`redline.worker.detection.store`), so two
    workers never open overlapping regressions.
    """
    flagged = session.execute(
        select(Detection, Series.process, Series.counter)
        .join(Series, Series.id == Detection.series_id)
        .where(
            Detection.revision_id == revision.id,
            Detection.flagged,
            Detection.method.in_(alarming),
        )
        .order_by(Detection.id)
    )
    for detection, process, counter in flagged:
        if detection.direction == worse(process, counter):  # not an improvement
            group_detection(session, detection, revision)
    session.flush()
    _fit(session, revision)
    _withdraw_emptied(session, revision.component_id)


def _fit(session: Session, revision: Revision) -> None:
    """The ranges of the regressions that reach the revision, made again from their changes'
    spans: judged again, a change can narrow (a revision reported late, or run afresh after the
    host was busy, between its baseline and it), and a range that only widened kept saying
    "between r2 and r4" of a change that was r4's against r3. A withdrawn or emptied one keeps
    the range it had."""
    reaching = session.scalars(
        select(Regression).where(
            Regression.component_id == revision.component_id,
            Regression.confirmation != WITHDRAWN,
            tuple_(Regression.good_key, Regression.good_revision_id) < revision.place,
            tuple_(Regression.bad_key, Regression.bad_revision_id) >= revision.place,
        )
    ).all()
    if not reaching:
        return
    baseline = aliased(Revision)
    goods: dict[int | None, list[tuple[str, int]]] = defaultdict(list)
    bads: dict[int | None, list[tuple[str, int]]] = defaultdict(list)
    for regression_id, good_key, good_id, bad_key, bad_id in session.execute(
        select(
            Detection.regression_id,
            baseline.order_key,
            baseline.id,
            Revision.order_key,
            Revision.id,
        )
        .join(baseline, baseline.id == Detection.baseline_revision_id)
        .join(Revision, Revision.id == Detection.revision_id)
        .where(Detection.regression_id.in_([r.id for r in reaching]))
    ):
        goods[regression_id].append((good_key, good_id))
        bads[regression_id].append((bad_key, bad_id))
    for regression in reaching:
        if regression.id not in goods:
            continue  # emptied: withdrawn (or deleted) next, with the range it had
        regression.good_key, regression.good_revision_id = min(goods[regression.id])
        regression.bad_key, regression.bad_revision_id = max(bads[regression.id])


def group_detection(session: Session, detection: Detection, revision: Revision) -> None:
    """Attach one flagged change for the worse of ``revision`` to the regression its span
    overlaps (widened to it), else to a new one; suspected until it is settled."""
    span = _span(session, detection, revision)
    if span is None:
        return
    good, bad = span
    regression = _overlapping(session, revision.component_id, good, bad)
    if regression is None:
        regression = Regression(
            component_id=revision.component_id,
            good_revision_id=good.id,
            bad_revision_id=bad.id,
            good_key=good.order_key,
            bad_key=bad.order_key,
            state=RegressionState.new,
        )
        session.add(regression)
        session.flush()
    else:
        _widen(regression, good, bad)
    detection.regression_id = regression.id
    detection.confirmation = SUSPECTED  # until the later revisions settle it
