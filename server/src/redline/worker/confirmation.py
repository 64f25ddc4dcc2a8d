"""Confirmation by history in the service: suspected changes settled by the revisions after them.

A flagged change for the worse is stored `SUSPECTED` (`grouping`). Whenever a revision of the
component is stored, every suspected detection of the component is looked at again: once
``confirm_revisions`` later revisions measured its series, `redline.detect.confirmation.hold`
says whether the change held or was a spike, from the stored per-execution summaries (no
samples are read). A regression is then *confirmed* when one of its changes held, *not
confirmed* when every one was dropped (its detections and figures stay), and *suspected* until
then. The outcome depends only on stored data, so a re-analysis, which stores revisions in
order with the later ones already ingested, settles each change as the incremental path does.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Collection, Mapping

import numpy as np
from redline.detect.confirmation import (
    DROPPED,
    FOUND_LATER,
    HOLD_SHARE,
    LATER_DECIDE,
    LOOKBACK,
    SUSPECTED,
    UNDECIDED,
    Hold,
    hold,
    relative_noise,
)
from redline.detect.counters import is_count
from redline.server.models import (
    FINISHED,
    Detection,
    Execution,
    Job,
    Revision,
    Series,
    Summary,
    revision_place,
)
from redline.server.services.fresh_runs import fresh_run_between, fresh_runs_under_way
from redline.server.services.reach import ingested_executions
from redline.worker.regression_summary import summarize_regressions
from sqlalchemy import exists, func, select
from sqlalchemy.orm import Session

#: later revisions with results, in multiples of the wait, after which a change whose series
#: they did not measure enough is dropped instead of waiting for ever
GONE_AFTER = 3


def _levels(session: Session, series_id: int, count: bool) -> list[tuple[str, int, np.ndarray]]:
    """The series' revisions in order, (sort key, revision id) as everywhere: (sort key,
    revision id, one value per execution). Ordered by execution within a sort key, revisions
    with one key (commits of one second) came in the order their runs did: a regression's
    revision after the unchanged one it followed read as a spike that returned. A phase measured
    while the host was busy is left out, as detection leaves it out: a busy spell after a flag
    would hold it, and one in the baseline would widen the bar a confirmation pair must pass."""
    value = Summary.mean if count else Summary.p50
    rows = session.execute(
        select(Revision.order_key, Revision.id, value)
        .join(Execution, Execution.id == Summary.execution_id)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(
            Summary.series_id == series_id,
            Summary.disturbed.is_(False),
            Execution.id.in_(ingested_executions()),
        )
        .order_by(Revision.order_key, Revision.id, Execution.id)
    )
    grouped: dict[tuple[str, int], list[float]] = defaultdict(list)
    for key, revision_id, number in rows:
        grouped[(key, revision_id)].append(number)
    return [(key, rid, np.asarray(v, dtype=float)) for (key, rid), v in grouped.items()]


def _baseline(levels: list[tuple[str, int, np.ndarray]], newest: int, pooled: int) -> np.ndarray:
    """The execution values of the baseline a detection was judged against: its ``pooled``
    revisions (at least one) up to the one at ``newest`` in ``levels`` (`_levels`)."""
    first = max(0, newest + 1 - max(1, pooled))
    return np.concatenate([values for _, _, values in levels[first : newest + 1]])


def baseline_values(
    session: Session, detection: Detection, series_id: int | None = None
) -> np.ndarray | None:
    """The execution values (medians) of the baseline the detection was judged against, from
    the stored summaries (of ``series_id`` over the same revisions, when given); None when they
    are gone."""
    levels = _levels(session, detection.series_id if series_id is None else series_id, False)
    return _baseline_of(levels, detection)


def _baseline_of(
    levels: list[tuple[str, int, np.ndarray]], detection: Detection
) -> np.ndarray | None:
    newest = next(
        (i for i, (_, rid, _) in enumerate(levels) if rid == detection.baseline_revision_id),
        None,
    )
    return None if newest is None else _baseline(levels, newest, detection.baseline_revisions)


def baseline_and_own(
    session: Session, detection: Detection
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """`baseline_values` and the execution values of the detection's own revision (measured
    undisturbed; None without any), from one read of the series' summaries."""
    levels = _levels(session, detection.series_id, False)
    own = next((v for _, rid, v in levels if rid == detection.revision_id), None)
    return _baseline_of(levels, detection), own


#: the fewest values a baseline's noise is read from (`baseline_noise`): the default method's
#: ``min_baseline``
NOISE_VALUES = 6


def baseline_noise(session: Session, detection: Detection, series_id: int | None = None) -> float:
    """How much one execution value of the detection's baseline varies, relative to its level
    (`redline.detect.confirmation.relative_noise`); NaN when its baseline's summaries are gone,
    or hold fewer than `NOISE_VALUES` values (a change judged at a new level of 3-5 values, a
    KS baseline of a revision or two), whose spread says little: the pairs' bar is then a share
    of the flagged step (`redline.detect.confirmation.pair_bar`), not a spread that three
    values can put near 0 (a review's simulation: two noise pairs passed 4.3 % of the time on
    3 values, 1.3 % on 15)."""
    values = baseline_values(session, detection, series_id)
    if values is None or np.isfinite(values).sum() < NOISE_VALUES:
        return math.nan
    return relative_noise(values)


def _later_revisions(session: Session, key: str, revision_id: int, detection: Detection) -> int:
    """How many revisions of the detection's component after (``key``, ``revision_id``) have
    results."""
    return int(
        session.scalar(
            select(func.count(func.distinct(Execution.revision_id)))
            .join(Revision, Revision.id == Execution.revision_id)
            .join(Series, Series.component_id == Revision.component_id)
            .where(
                Series.id == detection.series_id,
                revision_place() > (key, revision_id),
                Execution.id.in_(ingested_executions()),
            )
        )
        or 0
    )


def settle(
    session: Session,
    detection: Detection,
    process: str,
    counter: str,
    wait: int,
    changed: Collection[int] = (),
    fresh_runs: bool = True,
    returns: Mapping[int, Collection[int]] | None = None,
) -> None:
    """Settle one suspected detection if enough later revisions measured its series, counting
    only the revisions before the next one that itself changed (``changed``: the revisions with
    a flagged change of an alarming method, of any series, not dropped): a later change is no
    evidence for an earlier one; ``fresh_runs``: whether the component has a revision being
    run afresh, which a change spanning it waits for. (A
    trial's README commit was flagged on a noisy counter and "held" because the next revision
    raised CPU threefold, and that counter with it.)"""
    if detection.reason.startswith(FOUND_LATER):
        # its own runs missed the change (so it was found late): the history cannot settle it
        detection.confirmation, detection.confirmation_reason = (
            DROPPED,
            "not confirmed: found late, and its own pairs could not decide it ("
            f"{detection.confirmation_reason or 'none ran'}); its own runs missed the change",
        )
        return
    between = (
        fresh_run_between(session, detection.revision, [detection.baseline_revision_id])
        if fresh_runs
        else None
    )
    if between is not None:  # the change may be that revision's: settled once it ran again
        if not detection.confirmation_reason.startswith(UNDECIDED):  # what the re-runs said
            detection.confirmation_reason = (
                f"waiting for a fresh run of {between}, whose runs the host was busy in: the "
                "change may be its"
            )
        return
    count = is_count(process, counter)
    levels = _levels(session, detection.series_id, count)
    position = {rid: i for i, (_, rid, _) in enumerate(levels)}
    at = position.get(detection.revision_id)
    newest = position.get(detection.baseline_revision_id or -1)
    if at is None or newest is None:
        detection.confirmation, detection.confirmation_reason = (
            DROPPED,
            "not confirmed: the revision's or its baseline's summaries are gone",
        )
        return
    baseline = _baseline(levels, newest, detection.baseline_revisions)
    returned = returns or {}
    end = next(
        (
            i
            for i in range(at + 1, len(levels))
            if levels[i][1] in changed or detection.series_id in returned.get(levels[i][1], ())
        ),
        len(levels),
    )
    following = [values for _, _, values in levels[at + 1 : end]]
    before = [values for _, _, values in levels[max(0, at - LOOKBACK) : at]]
    past = np.concatenate(before) if before else np.array([])
    found = hold(baseline, levels[at][2], following, wait, count=count, past=past)
    if found.state == SUSPECTED and end < len(levels):
        found = _returned(baseline, levels, at, wait, count) or found
    if found.state == SUSPECTED and end < len(levels):
        again = (
            f"the series changed again {end - at} revision(s) later, before {wait} revision(s) "
            "could confirm it"
        )
        said = detection.confirmation_reason
        if said.startswith(UNDECIDED):  # what the re-runs said, and that the history cannot
            # (a trial's kept "the later revisions will confirm it instead" for good)
            head = said.split(f"; {LATER_DECIDE}")[0].split("; the series changed again")[0]
            detection.confirmation_reason = f"{head}; {again}: triage decides"
        else:
            detection.confirmation_reason = (
                f"suspected: {again}; re-runs (confirm_pairs) or triage decide"
            )
        return  # what follows the next change says nothing of this one
    later = (
        _later_revisions(session, levels[at][0], levels[at][1], detection)
        if found.state == SUSPECTED
        else 0
    )
    if found.state == SUSPECTED and later >= GONE_AFTER * wait:
        # the component went on without measuring it (a test renamed or removed): it cannot hold
        found = Hold(
            DROPPED,
            f"not confirmed: of the {later} revisions after it, {len(following)} measured the "
            "series",
            0.0,
        )
    if found.state == SUSPECTED and detection.confirmation_reason.startswith(UNDECIDED):
        return  # what the re-runs said stands until the history decides
    detection.confirmation, detection.confirmation_reason = found.state, found.reason


def _standing(
    session: Session, component_id: int, alarming: Collection[str]
) -> tuple[dict[int, set[int]], dict[int, set[int]]]:
    """Per revision, its flagged changes of the ``alarming`` methods that were not dropped, and
    that are not the return of a flag at their baseline revision (the same series and method
    flagged there the other way): a spike's next revision, judged against the spike alone, is
    flagged back, and counted as a change it kept every other change of the spike's revision
    suspected for ever. And per revision, the series such a return is of: for that series
    itself it is a change (`_returned` tells a return from a fall past the old level)."""
    flags = session.execute(
        select(
            Detection.id,
            Detection.revision_id,
            Detection.series_id,
            Detection.method,
            Detection.direction,
            Detection.baseline_revision_id,
            Detection.confirmation,
        )
        .join(Series, Series.id == Detection.series_id)
        .where(
            Series.component_id == component_id,
            Detection.flagged,
            Detection.method.in_(list(alarming)),
        )
    ).all()
    direction = {(f.series_id, f.method, f.revision_id): f.direction for f in flags}
    standing: dict[int, set[int]] = defaultdict(set)
    returns: dict[int, set[int]] = defaultdict(set)
    for flag in flags:
        before = direction.get((flag.series_id, flag.method, flag.baseline_revision_id))
        if flag.confirmation == DROPPED:
            continue
        if before not in (None, flag.direction):
            returns[flag.revision_id].add(flag.series_id)
            continue
        standing[flag.revision_id].add(flag.id)
    return standing, returns


def _returned(
    baseline: np.ndarray, levels: list[tuple[str, int, np.ndarray]], at: int, wait: int, count: bool
) -> Hold | None:
    """The flagged change at ``at`` dropped as a spike when the revisions after it returned
    towards the old level, the next change among them: that change may be the return itself
    (a spike's next revision, judged against the spike, is flagged the other way, and the spike
    stayed suspected for ever). Only a return counts across a later change, never a hold."""
    found = hold(baseline, levels[at][2], [v for _, _, v in levels[at + 1 :]], wait, count=count)
    if found.state == DROPPED and -HOLD_SHARE < found.kept < HOLD_SHARE:
        return found  # back near the old level: not a fall past it (a regression, then a fix)
    return None


def confirm_by_history(
    session: Session, component_id: int, wait: int, alarming: Collection[str]
) -> None:
    """Settle what the component's stored revisions can settle, then summarize regressions.

    A revision with a flagged change of the ``alarming`` methods ends what the revisions before
    it can confirm (`settle`), unless every such change of it was dropped (a spike is no
    change). The newest suspected changes are settled first, so that whether a later flag was
    dropped is known when an earlier one is settled: one pass reaches what repeated passes would.
    """
    # a revision whose confirmation runs are still under way waits for them
    # (`redline.worker.confirm_runs`, which leaves suspected what no complete pair can settle)
    rerun = exists().where(
        Job.confirms_revision_id == Detection.revision_id,
        Job.state.not_in(FINISHED),
    )
    suspected = session.execute(
        select(Detection, Series.process, Series.counter)
        .join(Series, Series.id == Detection.series_id)
        .join(Revision, Revision.id == Detection.revision_id)
        .where(
            Series.component_id == component_id,
            Detection.confirmation == SUSPECTED,
            ~rerun,
        )
        .order_by(Revision.order_key.desc(), Revision.id.desc(), Detection.id)
    ).all()
    # per revision with flagged changes, those not dropped: while any is left, it changed
    standing: dict[int, set[int]] = defaultdict(set)
    returns: dict[int, set[int]] = {}
    if suspected:
        standing, returns = _standing(session, component_id, alarming)
    changed = set(standing)
    # a revision being run afresh (`redline.worker.remeasure`): nearly always none
    fresh = session.scalar(fresh_runs_under_way(component_id).limit(1))
    for detection, process, counter in suspected:
        settle(session, detection, process, counter, wait, changed, fresh is not None, returns)
        if detection.confirmation == DROPPED and detection.revision_id in standing:
            standing[detection.revision_id].discard(detection.id)
            if not standing[detection.revision_id]:
                changed.discard(detection.revision_id)
    session.flush()
    summarize_regressions(session, component_id)
