"""Regressions: listing, triage with history, each method's precision from the triage labels,
and the stored detections behind them."""

from __future__ import annotations

from collections import defaultdict

from redline.server.models import (
    FALSE_POSITIVE_STATES,
    TRUE_POSITIVE_STATES,
    ApiToken,
    Detection,
    Regression,
    RegressionEvent,
    RegressionState,
    Revision,
    Series,
)
from redline.server.schemas.regressions import (
    AccuracyOut,
    DetectionOut,
    MethodAccuracy,
    RegressionDetail,
    RegressionEventOut,
    RegressionOut,
    TriageRequest,
)
from redline.server.services.components import get_component
from redline.server.services.errors import BadRequest, NotFound
from redline.server.services.results import series_ref
from sqlalchemy import Select, select
from sqlalchemy.orm import Session, aliased


def _methods(session: Session, ids: list[int]) -> dict[int, tuple[list[str], int]]:
    """Per regression: the methods that flagged in it, and how many detections it holds."""
    rows = session.execute(
        select(Detection.regression_id, Detection.method).where(Detection.regression_id.in_(ids))
    )
    found: dict[int, list[str]] = defaultdict(list)
    for regression_id, method in rows:
        if regression_id is not None:  # the query asks for some: typed as nullable all the same
            found[regression_id].append(method)
    return {i: (sorted(set(found[i])), len(found[i])) for i in ids}


def _out(regression: Regression, component: str, methods: list[str], count: int) -> dict:
    return dict(
        id=regression.id,
        component=component,
        good_revision=regression.good_revision.title,
        bad_revision=regression.bad_revision.title,
        state=regression.state.value,
        confirmation=regression.confirmation,
        confirmation_reason=regression.confirmation_reason,
        methods=methods,
        detections=count,
        created=regression.created,
        updated=regression.updated,
    )


def list_regressions(
    session: Session,
    component_name: str,
    state: str | None = None,
    confirmation: str | None = None,
) -> list[RegressionOut]:
    """The component's regressions, newest range first; ``state`` (triage) and
    ``confirmation`` (suspected, confirmed, not_confirmed) filter."""
    component = get_component(session, component_name)
    query = (
        select(Regression)
        .where(Regression.component_id == component.id)
        .order_by(Regression.bad_key.desc(), Regression.id.desc())
    )
    if state is not None:
        query = query.where(Regression.state == RegressionState(state))
    if confirmation is not None:
        query = query.where(Regression.confirmation == confirmation)
    regressions = list(session.scalars(query))
    methods = _methods(session, [r.id for r in regressions])
    return [RegressionOut(**_out(r, component.name, *methods[r.id])) for r in regressions]


def _get(session: Session, component_name: str, regression_id: int) -> Regression:
    component = get_component(session, component_name)
    regression = session.get(Regression, regression_id)
    if regression is None or regression.component_id != component.id:
        raise NotFound(f"component {component_name!r} has no regression {regression_id}")
    return regression


def _detections_query(component_id: int) -> Select:
    baseline = aliased(Revision)
    return (
        select(Detection, Series, Revision.title, baseline.title)
        .join(Series, Series.id == Detection.series_id)
        .join(Revision, Revision.id == Detection.revision_id)
        .outerjoin(baseline, baseline.id == Detection.baseline_revision_id)
        .where(Series.component_id == component_id)
    )


def _detection_out(row: tuple) -> DetectionOut:
    detection, series, title, base = row
    return DetectionOut(
        series=series_ref(series),
        revision=title,
        baseline=base,
        baseline_revisions=detection.baseline_revisions,
        method=detection.method,
        verdict=detection.verdict,
        reason=detection.reason,
        score=detection.score,
        p_value=detection.p_value,
        effect=detection.effect,
        direction=detection.direction,
        flagged=detection.flagged,
        confirmation=detection.confirmation,
        confirmation_reason=detection.confirmation_reason,
        regression_id=detection.regression_id,
    )


def regression_detail(
    session: Session, component_name: str, regression_id: int
) -> RegressionDetail:
    regression = _get(session, component_name, regression_id)
    rows = session.execute(
        _detections_query(regression.component_id)
        .where(Detection.regression_id == regression.id)
        .order_by(Revision.order_key, Series.id, Detection.method)
    )
    flagged = [_detection_out(row) for row in rows]
    history = [
        RegressionEventOut(
            at=e.at, who=e.who, from_state=e.from_state, to_state=e.to_state, comment=e.comment
        )
        for e in regression.events
    ]
    methods = sorted({d.method for d in flagged})
    return RegressionDetail(
        **_out(regression, component_name, methods, len(flagged)), flagged=flagged, history=history
    )


def triage(
    session: Session,
    component_name: str,
    regression_id: int,
    change: TriageRequest,
    token: ApiToken,
) -> RegressionDetail:
    """Move the regression to a new state and record who, when, from, to and why."""
    regression = _get(session, component_name, regression_id)
    new = RegressionState(change.state)
    if new == regression.state:
        raise BadRequest(f"regression {regression_id} is already {new.value!r}")
    regression.events.append(
        RegressionEvent(
            who=token.name,
            from_state=regression.state.value,
            to_state=new.value,
            comment=change.comment,
        )
    )
    regression.state = new
    session.commit()
    return regression_detail(session, component_name, regression_id)


def accuracy(session: Session, component_name: str) -> AccuracyOut:
    """Each method's precision on the labelled regressions it flagged.

    confirmed / fixed count as true positives, false_positive as a false positive; new,
    acknowledged and ignored are not labels.
    """
    component = get_component(session, component_name)
    rows = session.execute(
        select(Detection.method, Regression.id, Regression.state)
        .join(Regression, Regression.id == Detection.regression_id)
        .where(Regression.component_id == component.id)
        .distinct()
    )
    counts: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0])
    labelled: set[int] = set()
    for method, regression_id, state in rows:
        slot = 0 if state in TRUE_POSITIVE_STATES else 1 if state in FALSE_POSITIVE_STATES else 2
        counts[method][slot] += 1
        if slot < 2:
            labelled.add(regression_id)
    methods = [
        MethodAccuracy(
            method=m,
            true_positives=tp,
            false_positives=fp,
            precision=tp / (tp + fp) if tp + fp else None,
            unlabelled=rest,
        )
        for m, (tp, fp, rest) in sorted(counts.items())
    ]
    return AccuracyOut(
        component=component.name, labelled_regressions=len(labelled), methods=methods
    )


def list_detections(
    session: Session,
    component_name: str,
    revision: str | None = None,
    method: str | None = None,
    limit: int = 1000,
) -> list[DetectionOut]:
    """Stored verdicts, newest revision first; filtered by revision title and method."""
    component = get_component(session, component_name)
    query = _detections_query(component.id)
    if revision is not None:
        query = query.where(Revision.title == revision)
    if method is not None:
        query = query.where(Detection.method == method)
    query = query.order_by(
        Revision.order_key.desc(), Detection.flagged.desc(), Series.id, Detection.method
    ).limit(limit)
    return [_detection_out(row) for row in session.execute(query)]
