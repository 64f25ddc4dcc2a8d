"""The regressions of a component still open before a revision: what a CI job of a later commit
is told beside its own verdict. A trial's unchanged commits after a suspected regression each
passed `ci wait` with exit 0 and no word that the code they carried was suspected slower.

Open: standing (suspected or confirmed, not dropped by its confirmation runs nor withdrawn) and
not triaged away (new, acknowledged or confirmed; not fixed, ignored or a false positive), with
its change before the revision (the newest revision showing it earlier than this one).
"""

from __future__ import annotations

from collections.abc import Iterable

from redline.detect.comparison import params_name_of
from redline.detect.confirmation import DROPPED
from redline.server.models import (
    OPEN_STATES,
    STANDING,
    Detection,
    Regression,
    Revision,
    Series,
)
from redline.server.schemas.alerts import OpenRegression
from redline.server.schemas.regressions import RegressionOut
from sqlalchemy import ColumnElement, func, literal, select, true, tuple_
from sqlalchemy.dialects.postgresql import distinct_on
from sqlalchemy.orm import Session, aliased, selectinload

#: open regressions a verdict names at most (it counts them all)
NAMED = 3


def still_open() -> tuple[ColumnElement[bool], ...]:
    """The clauses of an open regression: standing and not triaged away. The home page counted
    regressions its confirmation runs had dropped (not_confirmed) as open."""
    return Regression.confirmation.in_(STANDING), Regression.state.in_(OPEN_STATES)


def series_label(case: str, phase: str, process: str, counter: str, params: str) -> str:
    """A series in words: "sweep/steady: builder uss_bytes [grid=60]" (without its test case
    and phase, a trial's two cases at rate=50 read as one)."""
    named = params_name_of(params)
    return f"{case}/{phase}: {process} {counter}" + (f" [{named}]" if named else "")


def largest_changes(
    session: Session, component_id: int | None, ids: Iterable[int] | None = None
) -> dict[int, str]:
    """Per regression of the component (of any component: None; of ``ids`` only, when given),
    its largest change in words ("builder cpu +208 % at r3"): the figures its summary keeps,
    which stay when it is withdrawn. A change confirmation dropped (a spike) is named only where
    the regression has no other: a trial's not-confirmed regressions were listed with none."""
    query = (
        select(Detection.regression_id, Detection.effect, Series.case, Series.phase)
        .add_columns(Series.process, Series.counter, Series.params, Revision.title)
        .join(Regression, Regression.id == Detection.regression_id)
        .join(Series, Series.id == Detection.series_id)
        .join(Revision, Revision.id == Detection.revision_id)
        .where(
            Regression.component_id == component_id if component_id is not None else true(),
            Detection.effect.is_not(None),
        )
        .ext(distinct_on(Detection.regression_id))
        .order_by(
            Detection.regression_id,
            Detection.confirmation == DROPPED,  # a spike it dropped is not its change
            func.abs(Detection.effect).desc(),
            Detection.id,
        )
    )
    if ids is not None:
        query = query.where(Detection.regression_id.in_(list(ids)))
    return {
        rid: f"{series_label(case, phase, process, counter, params)} {effect * 100:+.1f} % "
        f"at {title}"
        for rid, effect, case, phase, process, counter, params, title in session.execute(query)
        if rid is not None
    }


def open_before(session: Session, revision: Revision) -> tuple[list[OpenRegression], int]:
    """The component's open regressions whose change shows before ``revision``, newest first,
    at most `NAMED`; and how many there are in all."""
    where = (
        Regression.component_id == revision.component_id,
        *still_open(),
        tuple_(Regression.bad_key, Regression.bad_revision_id)
        < tuple_(literal(revision.order_key, Regression.bad_key.type), literal(revision.id)),
    )
    total = session.scalar(select(func.count()).select_from(Regression).where(*where)) or 0
    if not total:
        return [], 0
    found = session.scalars(
        select(Regression)
        .where(*where)
        .options(selectinload(Regression.good_revision), selectinload(Regression.bad_revision))
        .order_by(
            Regression.bad_key.desc(), Regression.bad_revision_id.desc(), Regression.id.desc()
        )
        .limit(NAMED)
    ).all()
    largest = largest_changes(session, revision.component_id, [r.id for r in found])
    back = changed_back(session, revision, [r.id for r in found])
    return [
        OpenRegression(
            id=regression.id,
            good_revision=regression.good_revision.title,
            bad_revision=regression.bad_revision.title,
            confirmation=regression.confirmation,
            state=regression.state.value,
            largest=largest.get(regression.id, ""),
            changed_back=back.get(regression.id, ""),
            page=f"/regressions/{regression.id}",
        )
        for regression in found
    ], total


def changed_back(session: Session, revision: Revision | None, ids: Iterable[int]) -> dict[int, str]:
    """Per regression of ``ids``, the newest revision after its change, up to ``revision`` (the
    newest revision: None), at
    which a series it holds was flagged changing the other way (a revert, a fix; not a flag its
    confirmation dropped, nor one followed by a flag the same way again, a reland), in words
    ("changed back at c12: plan/steady: planner cpu_refs_per_op [size=60] -28.5 %"). A sixth
    trial's revert passed as an improvement while its regression stayed open, and every later
    commit's CI job was told of it with no word that one since had undone it."""
    ours, back = aliased(Detection), aliased(Detection)
    bad, at = aliased(Revision), aliased(Revision)
    up_to = (
        true()
        if revision is None
        else tuple_(at.order_key, at.id)
        <= tuple_(literal(revision.order_key, at.order_key.type), literal(revision.id))
    )
    rows = session.execute(
        select(ours.regression_id, back.effect, Series.case, Series.phase)
        .add_columns(Series.process, Series.counter, Series.params, at.title)
        .add_columns(back.direction != ours.direction)
        .join(Regression, Regression.id == ours.regression_id)
        .join(bad, bad.id == Regression.bad_revision_id)
        .join(back, (back.series_id == ours.series_id) & (back.method == ours.method))
        .join(at, at.id == back.revision_id)
        .join(Series, Series.id == back.series_id)
        .where(
            ours.regression_id.in_(list(ids)),
            ours.flagged.is_(True),
            ours.confirmation.is_distinct_from(DROPPED),
            back.flagged.is_(True),
            back.confirmation.is_distinct_from(DROPPED),  # noise, not a change back
            back.direction.in_(("increase", "decrease")),
            back.regression_id.is_distinct_from(ours.regression_id),
            tuple_(at.order_key, at.id) > tuple_(bad.order_key, bad.id),
            up_to,
        )
        .order_by(ours.regression_id, at.order_key.desc(), at.id.desc())
    )
    said: dict[int, str] = {}
    seen: set[int] = set()
    for rid, effect, case, phase, process, counter, params, title, other_way in rows:
        if rid is None or rid in seen:
            continue
        seen.add(rid)  # the newest flag decides: one the same way since (a reland) undoes it
        if other_way:
            change = "" if effect is None else f" {effect * 100:+.1f} %"
            label = series_label(case, phase, process, counter, params)
            said[rid] = f"changed back at {title}: {label}{change}"
    return said


def open_in(titles: list[str], listed: Iterable[RegressionOut]) -> dict[str, list[RegressionOut]]:
    """Per revision of ``titles`` (newest first, consecutive), the open regressions of
    ``listed`` whose range holds it: after their good revision, up to their bad one (the
    component page's revision rows named none of them)."""
    place = {title: n for n, title in enumerate(titles)}
    marked: dict[str, list[RegressionOut]] = {}
    for regression in listed:
        if regression.confirmation not in STANDING or regression.state not in OPEN_STATES:
            continue
        bad = place.get(regression.bad_revision)
        if bad is None:  # older than the revisions listed
            continue
        good = place.get(regression.good_revision, len(titles))
        for title in titles[bad:good]:
            marked.setdefault(title, []).append(regression)
    return marked
