"""Regressions: listing, triage with history, each method's precision from the triage labels,
and the stored detections behind them."""

from __future__ import annotations

from collections import defaultdict

from redline.server.models import (
    FALSE_POSITIVE_STATES,
    OPEN_STATES,
    STANDING,
    TRUE_POSITIVE_STATES,
    WITHDRAWN,
    Component,
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
from redline.server.services.components import get_component, get_revision
from redline.server.services.errors import BadRequest, NotFound
from redline.server.services.open_regressions import changed_back, largest_changes
from redline.server.services.paging import after_newest_first, decode_cursor, encode_cursor
from redline.server.services.regression_range import revisions_between
from redline.server.services.results import series_ref
from sqlalchemy import Select, exists, literal, select, tuple_
from sqlalchemy.orm import Session, aliased, selectinload

#: the ``state`` filter's value for the triage states still open (`OPEN_STATES`)
OPEN = "open"
#: the ``confirmation`` filter's value for every confirmation, the withdrawn too (the page's)
ALL = "all"


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
        bad_subject=regression.bad_revision.subject,
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
    component_name: str | None,
    state: str | None = None,
    confirmation: str | None = None,
    limit: int | None = None,
    cursor: str | None = None,
    method: str | None = None,
) -> tuple[list[RegressionOut], str | None]:
    """The component's regressions, newest range first (every component's when None, newest
    first); ``state`` (triage; ``open``: new, acknowledged or confirmed, and standing unless
    ``confirmation`` says otherwise), ``confirmation``
    (suspected, confirmed, not_confirmed, withdrawn, standing: suspected or confirmed, or all) and
    ``method`` (one of the methods that flagged a change in it) filter; ``limit`` of them
    after ``cursor``, and the next page's cursor (None after the last)."""
    query = (
        select(Regression, Component.name)
        .join(Component, Component.id == Regression.component_id)
        .options(selectinload(Regression.good_revision), selectinload(Regression.bad_revision))
    )  # the ranges' revisions in two reads, not two a regression
    if component_name is not None:
        component = get_component(session, component_name)
        query = query.where(Regression.component_id == component.id).order_by(
            Regression.bad_key.desc(), Regression.id.desc()
        )
        if cursor:
            key, last = decode_cursor(cursor, str, int)
            query = query.where(
                tuple_(Regression.bad_key, Regression.id)
                < tuple_(literal(key, Regression.bad_key.type), literal(last))
            )
    else:
        query = query.order_by(Regression.id.desc())
        if cursor:
            (last,) = decode_cursor(cursor, int)
            query = query.where(Regression.id < last)
    if state == OPEN:
        query = query.where(Regression.state.in_(OPEN_STATES))
    elif state is not None:
        query = query.where(Regression.state == RegressionState(state))
    if state == OPEN and confirmation is None:  # as the home page counts them
        query = query.where(Regression.confirmation.in_(STANDING))
    elif state is not None and confirmation is None:
        # a triage queue holds what is still found, not the withdrawn
        query = query.where(Regression.confirmation != WITHDRAWN)
    if confirmation == "standing":
        query = query.where(Regression.confirmation.in_(STANDING))
    elif confirmation not in (None, ALL):
        query = query.where(Regression.confirmation == confirmation)
    if method is not None:
        flagged_by = exists().where(
            Detection.regression_id == Regression.id, Detection.method == method
        )
        query = query.where(flagged_by)
    found = [(regression, name) for regression, name in session.execute(query.limit(limit))]
    following = None
    if limit is not None and len(found) == limit:
        end = found[-1][0]
        following = (
            encode_cursor(end.bad_key, end.id)
            if component_name is not None
            else encode_cursor(end.id)
        )
    methods = _methods(session, [regression.id for regression, _ in found])
    largest = largest_changes(session, None, [regression.id for regression, _ in found])
    return [
        RegressionOut(**_out(r, name, *methods[r.id]), largest=largest.get(r.id, ""))
        for r, name in found
    ], following


def detection_by_id(session: Session, detection_id: int) -> tuple[Detection, DetectionOut]:
    """A stored verdict by its id, as stored and as the API shows it; NotFound naming it."""
    detection = session.get(Detection, detection_id)
    if detection is None:
        raise NotFound(f"no detection {detection_id}")
    component_id = session.get_one(Series, detection.series_id).component_id
    row = session.execute(_detections_query(component_id).where(Detection.id == detection_id)).one()
    return detection, _detection_out(tuple(row))


def component_of(session: Session, regression_id: int) -> str:
    """The name of the component a regression belongs to; NotFound naming the id otherwise."""
    name = session.scalar(
        select(Component.name)
        .join(Regression, Regression.component_id == Component.id)
        .where(Regression.id == regression_id)
    )
    if name is None:
        raise NotFound(f"no regression {regression_id}")
    return name


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
        id=detection.id,
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
    between, count = revisions_between(session, regression)
    back = changed_back(session, None, [regression.id])  # up to the newest revision
    return RegressionDetail(
        **_out(regression, component_name, methods, len(flagged)),
        largest=largest_changes(session, regression.component_id, [regression.id]).get(
            regression.id, ""
        ),
        flagged=flagged,
        history=history,
        between=between,
        between_count=count,
        changed_back=back.get(regression.id, ""),
    )


def triage(
    session: Session,
    component_name: str,
    regression_id: int,
    change: TriageRequest,
    who: str,
) -> RegressionDetail:
    """Move the regression to a new state and record who (a token's or a signed-in person's
    name), when, from, to and why."""
    regression = _get(session, component_name, regression_id)
    new = RegressionState(change.state)
    if new == regression.state:
        raise BadRequest(f"regression {regression_id} is already {new.value!r}")
    regression.events.append(
        RegressionEvent(
            who=who,
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
    cursor: str | None = None,
) -> tuple[list[DetectionOut], str | None]:
    """Stored verdicts, newest revision first, flagged first within it; filtered by revision
    title and method; ``limit`` of them after ``cursor``, and the next page's cursor (None
    after the last)."""
    component = get_component(session, component_name)
    query = _detections_query(component.id).add_columns(Revision.order_key)
    if revision is not None:
        query = query.where(Revision.id == get_revision(session, component, revision).id)
    if method is not None:
        query = query.where(Detection.method == method)
    after = after_newest_first(cursor, Revision.order_key, Detection.flagged, Detection.id)
    if after is not None:
        query = query.where(after)
    query = query.order_by(Revision.order_key.desc(), Detection.flagged.desc(), Detection.id).limit(
        limit
    )
    rows = list(session.execute(query))
    following = None
    if len(rows) == limit:
        last, *_, key = rows[-1]
        following = encode_cursor(key, last.flagged, last.id)
    return [_detection_out(tuple(row)[:4]) for row in rows], following
