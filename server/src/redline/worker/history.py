"""What detection asks of a component's stored history: the earlier revisions with samples of a
series, the verdicts flagged so far, the configuration in force (the later revisions a late
arrival reaches: `redline.worker.onward`)."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Collection, Sequence

from redline.detect.confirmation import BY_PAIRS, DROPPED, HELD
from redline.detect.counters import (
    CONTEXT_COUNTERS,
    LEVELS,
    driver_metric,
    is_count,
    judged_among,
)
from redline.detect.result import NOT_ENOUGH_DATA
from redline.recording import SeriesKey
from redline.server.models import (
    Detection,
    Execution,
    Reanalysis,
    Revision,
    Series,
    Summary,
    revision_place,
)
from redline.server.services.reach import ingested_executions
from sqlalchemy import ColumnElement, func, select
from sqlalchemy.orm import Session


def ingested_fingerprint(session: Session, component_id: int) -> tuple[int, int]:
    """How many executions of the component are ingested, and the newest one's id: it changes
    whenever an execution is ingested (or removed), so a re-analysis can tell its memory of the
    history went stale."""
    count, newest = session.execute(
        select(func.count(Execution.id), func.coalesce(func.max(Execution.id), 0))
        .join(Revision, Revision.id == Execution.revision_id)
        .where(Revision.component_id == component_id, Execution.id.in_(ingested_executions()))
    ).one()
    return int(count), int(newest)


def summarized_series(session: Session, revision_id: int) -> frozenset[int]:
    return frozenset(
        session.scalars(
            select(Summary.series_id)
            .distinct()
            .join(Execution, Execution.id == Summary.execution_id)
            .where(Execution.revision_id == revision_id)
        )
    )


def earlier_than(revision: Revision):  # noqa: ANN202 - an SQL expression
    return revision_place() < revision.place


def judged_counters(
    session: Session,
    series_ids: Collection[int],
    context: Collection[str] = CONTEXT_COUNTERS,
    known: dict[int, SeriesKey] | None = None,
    levels: Collection[str] = LEVELS,
) -> dict[int, tuple[str, str]]:
    """Series id → (process, counter), of the series among ``series_ids`` (one revision's) a
    verdict is asked of by methods judging at ``levels`` (`redline.detect.counters.judged_among`:
    not the host's, not a context counter, not a driver's load, of a CPU share and its CPU per
    unit of work the one such methods judge). ``known``: the names read so far (a re-analysis's
    memory; a series' names never change), brought up to date."""
    known = {} if known is None else known
    unknown = [series_id for series_id in series_ids if series_id not in known]
    if unknown:
        rows = session.execute(
            select(
                Series.id, Series.case, Series.phase, Series.params, Series.process, Series.counter
            ).where(Series.id.in_(unknown))
        )
        known.update((row[0], SeriesKey(*row[1:])) for row in rows)
    ids = {known[series_id]: series_id for series_id in series_ids if series_id in known}
    return {ids[key]: (key.process, key.counter) for key in judged_among(ids, context, levels)}


def newest_with_summaries(session: Session, revision: Revision, depth: int) -> list[int]:
    has_samples = (
        select(Summary.id)
        .join(Execution, Execution.id == Summary.execution_id)
        .where(Execution.revision_id == Revision.id)
        .exists()
    )
    return list(
        session.scalars(
            select(Revision.id)
            .where(
                Revision.component_id == revision.component_id, earlier_than(revision), has_samples
            )
            .order_by(Revision.order_key.desc(), Revision.id.desc())
            .limit(depth)
        )
    )


def ranked_previous(
    session: Session, revision: Revision, series_ids: list[int], depth: int
) -> dict[int, list[int]]:
    """Per series, the ids of the ``depth`` newest earlier revisions with samples of it, by
    ranking every earlier revision's summaries of those series (the general case)."""
    rank = func.dense_rank().over(
        partition_by=Summary.series_id, order_by=(Revision.order_key.desc(), Revision.id.desc())
    )
    ranked = (
        select(Summary.series_id, Revision.id.label("revision_id"), rank.label("rank"))
        .join(Execution, Execution.id == Summary.execution_id)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(
            Revision.component_id == revision.component_id,
            Summary.series_id.in_(series_ids),
            earlier_than(revision),
        )
        .subquery()
    )
    rows = session.execute(
        select(ranked.c.series_id, ranked.c.revision_id, ranked.c.rank)
        .where(ranked.c.rank <= depth)
        .distinct()
        .order_by(ranked.c.series_id, ranked.c.rank)
    )
    found: dict[int, list[int]] = defaultdict(list)
    for series_id, revision_id, _rank in rows:
        if revision_id not in found[series_id]:
            found[series_id].append(revision_id)
    return found


def previous_revisions(
    session: Session,
    revision: Revision,
    series_ids: list[int],
    depth: int,
    known: Sequence[tuple[int, frozenset[int]]] | None = None,
) -> dict[int, list[int]]:
    """Per series, the ids of the ``depth`` newest earlier revisions with samples of it.

    The newest ``depth`` earlier revisions with results nearly always hold every series: they
    are looked up first (an index walk, whatever the history's length), or taken from ``known``
    (newest first, each with the series it has summaries of: a re-analysis's `Walk`); only the
    series some of them lack are ranked over the whole history. Ranking every series each time
    made a re-analysis quadratic in the history's length.
    """
    holds: dict[int, set[int]] = defaultdict(set)
    if known is not None:
        newest = [revision_id for revision_id, _ in known[:depth]]
        for revision_id, series in known[:depth]:
            for series_id in series:
                holds[series_id].add(revision_id)
    else:
        newest = newest_with_summaries(session, revision, depth)
    if newest and known is None:
        rows = session.execute(
            select(Summary.series_id, Execution.revision_id)
            .distinct()
            .join(Execution, Execution.id == Summary.execution_id)
            .where(Execution.revision_id.in_(newest), Summary.series_id.in_(series_ids))
        )
        for series_id, revision_id in rows:
            holds[series_id].add(revision_id)
    found = {series_id: [r for r in newest if r in holds[series_id]] for series_id in series_ids}
    # fewer than `depth` revisions with results: there is nothing older to look through
    lacking = [s for s in series_ids if len(found[s]) < depth] if len(newest) == depth else []
    if lacking:
        found.update(ranked_previous(session, revision, lacking, depth))
    return {series_id: ids for series_id, ids in found.items() if ids}


def flagged_verdicts(
    session: Session, revision_ids: set[int], series_ids: list[int] | None = None
) -> set[tuple[int, str, int]]:
    """(series, method, revision) of the stored flagged verdicts of those revisions (and of
    those series, when given)."""
    return _verdicts_where(session, Detection.flagged.is_(True), revision_ids, series_ids)


def flagged_and_confirmed(
    session: Session, revision_ids: set[int], series_ids: list[int] | None = None
) -> tuple[set[tuple[int, str, int]], set[tuple[int, str, int]]]:
    """`flagged_verdicts` but those dropped, and those of them their pairs confirmed as changes
    (the history's confirmations the baseline reads from the revisions after them, as a
    re-analysis does), in one query. A dropped flag is no level, and a baseline reads on past
    it as past any revision: in a sixth trial a README-only commit's round trip, flagged on a
    busy host and dropped by its pair, restarted the baseline, the slow commit after it was
    "not enough data" against that one revision, and the unchanged commit after the slow one
    was flagged and failed CI (a re-analysis, which settles confirmations at its end, reads
    such a flag as undecided: the revisions after it decide it, a known difference)."""
    if not revision_ids:
        return set(), set()
    by_pairs = (Detection.confirmation == HELD) & Detection.confirmation_reason.startswith(BY_PAIRS)
    query = select(Detection.series_id, Detection.method, Detection.revision_id, by_pairs).where(
        Detection.flagged.is_(True),
        Detection.confirmation.is_distinct_from(DROPPED),
        Detection.revision_id.in_(revision_ids),
    )
    if series_ids is not None:
        query = query.where(Detection.series_id.in_(series_ids))
    flagged: set[tuple[int, str, int]] = set()
    confirmed: set[tuple[int, str, int]] = set()
    for series_id, method, revision_id, paired in session.execute(query):
        flagged.add((series_id, method, revision_id))
        if paired:
            confirmed.add((series_id, method, revision_id))
    return flagged, confirmed


def undecided_verdicts(
    session: Session, revision_ids: set[int], series_ids: list[int] | None = None
) -> set[tuple[int, str, int]]:
    """(series, method, revision) of the stored "not enough data" verdicts of those revisions
    (and series): where a step may be found later (`redline.worker.baselines`)."""
    return _verdicts_where(session, Detection.verdict == NOT_ENOUGH_DATA, revision_ids, series_ids)


def _verdicts_where(
    session: Session,
    condition: ColumnElement[bool],
    revision_ids: set[int],
    series_ids: list[int] | None,
) -> set[tuple[int, str, int]]:
    if not revision_ids:
        return set()
    query = select(Detection.series_id, Detection.method, Detection.revision_id).where(
        condition, Detection.revision_id.in_(revision_ids)
    )
    if series_ids is not None:
        query = query.where(Detection.series_id.in_(series_ids))
    rows = session.execute(query)
    return {(series_id, method, revision_id) for series_id, method, revision_id in rows}


def _totals_named(series: Series) -> list[str]:
    """The counters a count series may count out of: its action's fields named by ``of``."""
    metric = driver_metric(series.process, series.counter)
    stem = series.counter.rpartition(":")[0]
    return [f"{stem}:{of}" if stem else of for of in (metric.of if metric else ())]


def count_totals(session: Session, series_ids: Collection[int]) -> dict[int, int]:
    """For each series counting rare events (a driver's timeouts, losses), the series of what
    it counts out of (the queries sent...: the first of the metric's ``of`` fields that exists
    for the same action); a count without one is left out."""
    if not series_ids:
        return {}
    counts = [
        series
        for series in session.scalars(select(Series).where(Series.id.in_(series_ids)))
        if is_count(series.process, series.counter)
    ]
    if not counts:
        return {}
    names = {name for series in counts for name in _totals_named(series)}
    found = {
        (s.component_id, s.case, s.phase, s.params, s.process, s.counter): s.id
        for s in session.scalars(
            select(Series).where(
                Series.component_id.in_({series.component_id for series in counts}),
                Series.counter.in_(names),
            )
        )
    }
    totals: dict[int, int] = {}
    for series in counts:
        place = (series.component_id, series.case, series.phase, series.params, series.process)
        total = next(
            (found[(*place, name)] for name in _totals_named(series) if (*place, name) in found),
            None,
        )
        if total is not None:
            totals[series.id] = total
    return totals


def no_longer_measured(
    session: Session,
    revision: Revision,
    candidate: Collection[int],
    context: Collection[str],
    known: Sequence[tuple[int, frozenset[int]]] | None = None,
) -> list[int]:
    """The judged series that the newest earlier revision with results measured, in a test case
    this one measured too, and this one does not (a phase or action removed or renamed, or a
    driver report missing): each is reported once, where it disappears. A test case this
    revision did not run at all is another suite's, not a measurement it lost: results imported
    between agent-run revisions (a trial's LNT import sorting before them) made the next one's
    CI verdict undecided. ``known``: a re-analysis's memory of the newest earlier revisions
    (newest first, with their series)."""
    if known is not None:
        previous = known[0][1] if known else frozenset()
    else:
        newest = newest_with_summaries(session, revision, 1)
        previous = summarized_series(session, newest[0]) if newest else frozenset()
    gone = sorted(previous - set(candidate))
    if not gone:
        return []
    cases = {
        series_id: case
        for series_id, case in session.execute(
            select(Series.id, Series.case).where(Series.id.in_([*gone, *candidate]))
        )
    }
    ran = {cases[series_id] for series_id in candidate if series_id in cases}
    lost = [series_id for series_id in gone if cases.get(series_id) in ran]
    return sorted(judged_counters(session, lost, context)) if lost else []


def reanalysing(session: Session, component_id: int) -> bool:
    """A re-analysis of the component is storing its verdicts: the later revisions' verdicts
    are a mix of old and new, so settling by history waits for the run's end, which settles
    once for the component (`redline.worker.reanalysis_finish.finish`; the component's row,
    locked by both, orders the two), and no machine time is queued for old revisions."""
    state = session.scalar(select(Reanalysis.state).where(Reanalysis.component_id == component_id))
    return state == "running"
