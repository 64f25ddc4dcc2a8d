"""Detection over stored results: each series of a revision against its baseline, every method.

The component's configuration (`redline.detect.config.DetectionConfig`, table ``detection_config``;
defaults when absent) names the methods and the baseline: ``recent`` (the newest earlier revisions
with samples of the series, pooled until the method has enough values, restarting at the method's
newest flagged change; `redline.detect.baseline`), the previous revision (by sort key), a window of
the previous n such revisions pooled, or a pinned revision. Execution-level methods get one value
per execution (its median), the others all samples. Every method's verdict on every series is stored
as a `Detection` — "not enough data" with the reason included (no baseline, too few samples,
constant, NaN/inf); KS's decided ones are what the trend charts and
``/api/v1/components/{name}/changes`` show. Flagged detections are then grouped into regressions
(`redline.worker.grouping`). Host-wide series are context, never judged.

The parts: `samples` (the Parquet side tables written at ingestion), `history` (what is asked of
the stored history), `baselines` (the baseline policy), `rows` (what is stored), and here the
transactions: a revision is judged and stored under its lock.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from redline.detect.config import DetectionConfig
from redline.detect.count_rate import CountRate
from redline.detect.counters import is_count
from redline.detect.execution_shift import STEP_FOUND
from redline.detect.methods import Detector
from redline.detect.result import NO_CHANGE, NOT_MEASURED, SHORT_BASELINE, not_enough
from redline.detect.result import Detection as Verdict
from redline.detect.verdict import judge_series
from redline.server.db import bulk_insert, lock_component, lock_revision, session_scope
from redline.server.models import Detection, Revision, utcnow
from redline.server.services.analysed import inputs_seen, mark_analysed
from redline.server.services.detection_config import component_config, judging_config_id
from redline.worker.baselines import Baseline, Baselines
from redline.worker.confirm_runs import queue_confirmations, settle_pending_pairs
from redline.worker.confirmation import confirm_by_history
from redline.worker.found_late import still_moved
from redline.worker.grouping import group_revision
from redline.worker.held_level import confirm_held, held_level, rerunnable_only
from redline.worker.history import (
    count_totals,
    judged_counters,
    no_longer_measured,
    reanalysing,
)
from redline.worker.remeasure import queue_for_baselines
from redline.worker.rows import Judged, KsChange, detection_row, ks_change, step_row
from redline.worker.samples import Samples, read_samples
from sqlalchemy import Table, delete, select
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from redline.worker.reanalysis import Walk


#: what follows a short baseline's reason (`redline.detect.result.SHORT_BASELINE`) when
#: executions of the baseline's revisions gave no value
LEFT_OUT = (
    "execution(s) of its revisions left out (measured while the host was busy, or without "
    "this series)"
)


def analyze(
    session: Session,
    revision: Revision,
    config: DetectionConfig,
    candidate: Samples | None = None,
    walk: Walk | None = None,
    unjudged: dict[int, str] | None = None,
    only: Callable[[int], bool] | None = None,
    partial: dict[int, str] | None = None,
) -> tuple[list[dict[str, Any]], list[KsChange]]:
    """Every configured method on every judged series of the revision (nothing stored); counts
    of rare events by `CountRate`; a series no longer measured, "not enough data" saying so.

    ``candidate``: the revision's samples, when already read, and ``unjudged`` the series only
    executions not to be judged hold, with the reason (`read_samples`): each method answers
    "not enough data" with it. ``walk``: what a re-analysis carries from the earlier revisions;
    ``only``: the series a re-analysis's part judges (a count's total is read all the same);
    ``partial``: the series some executions lacked, each verdict's reason then saying how many.
    """
    if candidate is None:
        candidate, _, _, unjudged, partial = read_samples(session, revision.id)
    partial = partial or {}
    unjudged = {s: why for s, why in (unjudged or {}).items() if s not in candidate}
    gone = no_longer_measured(
        session,
        revision,
        [*candidate, *unjudged],
        config.context_counters,
        walk.newest_first() if walk else None,
    )
    # nothing of the revision may be judged (say the component took no part): that is also why
    # a series is missing from it
    missing = next(iter(unjudged.values())) if unjudged and not candidate else NOT_MEASURED
    absent = {**dict.fromkeys(gone, missing), **unjudged}
    detectors = config.detectors()
    names = walk.names if walk else {}

    def judged_at(level: str) -> dict[int, tuple[str, str]]:
        """The series methods at ``level`` judge: of a CPU share and its CPU per unit of work,
        the one at that level (`judged_counters`), chosen among all the revision's measured
        series, then among its absent ones (a revision whose runs lost the host's reference
        has its share judged), before a re-analysis's part takes its own: parts split the two
        figures of a segment, and each part alone would judge both."""
        found = {
            **judged_counters(session, list(candidate), config.context_counters, names, (level,)),
            **judged_counters(session, list(absent), config.context_counters, names, (level,)),
        }
        return {s: named for s, named in found.items() if only is None or only(s)}

    by_level = {level: judged_at(level) for level in config.levels}
    judged = {k: v for at_level in by_level.values() for k, v in at_level.items()}
    baselines = Baselines(session, revision, config, sorted(candidate.keys() & judged), walk)
    baselines.cache.put(revision.id, candidate)
    counts = {s for s, (process, counter) in judged.items() if is_count(process, counter)}

    def asking(series_id: int) -> list[Detector]:
        return [d for d in detectors if series_id in by_level[d.level]]

    rows = [
        detection_row(series_id, revision.id, Baseline(None), not_enough(name, why))
        for series_id, why in sorted(absent.items())
        if series_id in judged
        for name in (
            [CountRate.name] if series_id in counts else [d.name for d in asking(series_id)]
        )
    ]
    totals = count_totals(session, counts)
    changes = []
    # judged new: a re-analysis queues no pairs, which alone may confirm a level found so
    watch_held = walk is None and config.confirms
    for series_id in sorted(judged.keys() - absent.keys()):
        if series_id in counts:
            base, verdict = _judge_count(baselines, revision.id, series_id, totals.get(series_id))
            verdict = _noted(verdict, partial.get(series_id))
            rows.append(detection_row(series_id, revision.id, base, verdict))
            continue
        counter = judged[series_id][1]
        for detector in asking(series_id):
            values = baselines.values(revision.id, series_id, detector)
            step = _step(baselines, revision, series_id, detector, counter, values)
            if step is not None:
                rows.append(step)
            base = baselines.of(series_id, detector)
            verdict = judge_series(detector, counter, base.values, values, missing=base.missing)
            base, verdict = baselines.after_flag(
                series_id, detector, counter, values, base, verdict
            )
            if watch_held and verdict.verdict == NO_CHANGE:
                found = baselines.held(series_id, detector, values)
                held = held_level(series_id, found, counter, revision)
                if held is not None:
                    rows.append(held)
            if base.values is not None and verdict.reason.startswith(SHORT_BASELINE):
                left = baselines.left_out(series_id, detector, len(base.values))
                if left:
                    verdict = replace(verdict, reason=f"{verdict.reason}; {left} {LEFT_OUT}")
            verdict = _noted(verdict, partial.get(series_id))
            rows.append(detection_row(series_id, revision.id, base, verdict))
            change = ks_change(rows[-1], verdict)
            if change is not None:
                changes.append(change)
    return rows, changes


def _noted(verdict: Verdict, note: str | None) -> Verdict:
    """``verdict`` with ``note`` after its reason: a series judged on fewer executions than
    the revision ran is never judged so silently."""
    if not note:
        return verdict
    return replace(verdict, reason=f"{verdict.reason}; {note}" if verdict.reason else note)


def _step(
    baselines: Baselines,
    revision: Revision,
    series_id: int,
    detector: Detector,
    counter: str,
    values: np.ndarray | None,
) -> dict[str, Any] | None:
    """The verdict of an earlier revision that could not be judged when it was measured, when
    this revision shows that the series stepped there (`Baselines.step`); the baselines then
    start at it, this revision's included. None when there is no such step."""
    row = step_row(
        series_id,
        baselines.step(series_id, detector, values),
        counter,
        lambda step: (
            f"{STEP_FOUND}{revision.title} was judged: it could not be judged when "
            f"measured (too few values before it); its {len(step.after)} values and those after "
            f"it against the {step.values_before} before it"
        ),
    )
    if row is not None:
        baselines.restart(series_id, detector, row["revision_id"])
    return row


def _judge_count(
    baselines: Baselines, revision_id: int, series_id: int, total_id: int | None
) -> tuple[Baseline, Verdict]:
    """A count of rare events judged as a rate (`CountRate`), out of its total (``total_id``),
    each summed over the baseline's revisions and over the candidate's executions."""
    judge = CountRate()
    if total_id is None:
        return Baseline(None), not_enough(
            judge.name,
            "nothing says what these events are counted out of (the queries or samples sent)",
        )
    found = baselines.revisions_of(series_id, judge)
    if not found:
        base = baselines.of(series_id, judge)
        return base, not_enough(judge.name, base.missing)

    def summed(revision: int, series: int) -> float:
        values = baselines.values(revision, series, judge)
        return float(np.sum(values)) if values is not None else math.nan

    verdict = judge.compare(
        sum(summed(r, series_id) for r in found),
        sum(summed(r, total_id) for r in found),
        summed(revision_id, series_id),
        summed(revision_id, total_id),
    )
    return Baseline(None, newest=found[0], revisions=len(found)), verdict


def store(
    session: Session,
    revision: Revision,
    rows: list[dict[str, Any]],
    rerun: bool = False,
    config: DetectionConfig | None = None,
) -> None:
    """Replace the revision's detections, regroup its regressions, queue or judge its
    confirmation runs (`redline.worker.confirm_runs`), queue a fresh run of a baseline the host
    was busy in (`redline.worker.remeasure`), and settle what the later revisions can confirm
    (`redline.worker.confirmation`). The caller marks the revision analysed
    (`redline.server.services.analysed.mark_analysed`), with the inputs it read before judging.

    One statement (`bulk_insert`): 500 series x 2 methods would otherwise spend more time in
    the ORM and in round trips than in the detectors.
    """
    # the component's row first: grouping and confirmation update other revisions' rows, and
    # two stores of one component taking their locks in different orders would deadlock
    lock_component(session, revision.component_id)
    config = config or component_config(session, revision.component_id)
    config_id = judging_config_id(session, revision.component_id, config)
    rows = [row | {"config_id": config_id} for row in rows]
    own = [row for row in rows if row["revision_id"] == revision.id]
    earlier = rerunnable_only(session, [row for row in rows if row["revision_id"] != revision.id])
    _store_steps(session, earlier, config)
    kept = still_moved(
        session,
        revision.id,
        ((r["series_id"], r["method"], r["verdict"], r["reason"]) for r in own),
    )
    own = [row for row in own if (row["series_id"], row["method"]) not in kept]
    session.execute(
        delete(Detection).where(
            Detection.revision_id == revision.id, Detection.id.not_in(list(kept.values()))
        )
    )
    bulk_insert(session, cast(Table, Detection.__table__), own)
    group_revision(session, revision, config.alarming)
    if rerun:  # new results only: a re-analysis never queues machine time for old revisions
        queue_for_baselines(session, revision, own, config.baseline)  # first: pairs wait on it
        queue_confirmations(session, revision, config)
        confirm_held(session, earlier)
    settle_pending_pairs(session, revision.component_id)
    if not reanalysing(session, revision.component_id):
        confirm_by_history(
            session, revision.component_id, config.confirm_revisions, config.alarming
        )


def _store_steps(session: Session, rows: list[dict[str, Any]], config: DetectionConfig) -> None:
    """The verdicts of earlier revisions a step or a held level was found at (`_step`,
    `held_level`), each replacing that revision's verdict of its series and method, grouped
    into regressions (the earlier revisions first, as a re-analysis stores them)."""
    if not rows:  # nearly always: no step found
        return
    for row in rows:
        session.execute(
            delete(Detection).where(
                Detection.revision_id == row["revision_id"],
                Detection.series_id == row["series_id"],
                Detection.method == row["method"],
            )
        )
    bulk_insert(session, cast(Table, Detection.__table__), rows)
    earlier = session.scalars(
        select(Revision)
        .where(Revision.id.in_({row["revision_id"] for row in rows}))
        .order_by(Revision.order_key, Revision.id)
    )
    for revision in earlier:
        group_revision(session, revision, config.alarming)


def judge_revision(
    session: Session,
    revision_id: int,
    walk: Walk | None = None,
    only: Callable[[int], bool] | None = None,
    config: DetectionConfig | None = None,
) -> Judged | None:
    """The reading half of `detect_revision`: every verdict computed, nothing stored.

    None when there is nothing to store: no such revision, or ingested executions none of whose
    samples can be read any more (pruned), whose stored results are kept (nothing is not a new
    verdict). ``walk``: a re-analysis's memory of the earlier revisions, brought up to date;
    ``only``: the series its part judges; ``config``: the configuration to judge by (a
    re-analysis's, `redline.worker.reanalysis_finish.run_config`), else the component's.
    """
    revision = session.get(Revision, revision_id)
    if revision is None:
        return None
    candidate, read, executions, unjudged, partial = read_samples(session, revision.id)
    if executions and not read:
        log.warning(
            "revision %s: the samples of its %d executions are gone (pruned?); "
            "its stored results are kept",
            revision_id,
            len(executions),
        )
        if walk is not None:
            walk.kept(session, revision_id)
        return None
    # a re-analysis judges with the configuration it began with (a change queues another)
    if walk is not None:
        config = walk.config
    config = config or component_config(session, revision.component_id)
    rows, changes = analyze(session, revision, config, candidate, walk, unjudged, only, partial)
    if walk is not None:
        walk.judged(session, revision.id, candidate, rows, read == len(executions), set(unjudged))
    return Judged(revision.id, rows, changes, executions)


def detect_revision(database_url: str, revision_id: int) -> list[KsChange]:
    """Run the component's methods on every series of the revision, replacing earlier results.

    Returns KS's changes (a series without a baseline has none; its detections say "not
    enough data: missing baseline"). Reading and storing happen under the revision's lock, in
    one transaction; a revision whose samples were all pruned keeps its stored results.
    """
    judged = detect_and_store(database_url, revision_id)
    return [] if judged is None else judged.changes


def detect_and_store(database_url: str, revision_id: int) -> Judged | None:
    """`detect_revision`, returning all it stored (None: nothing): the rows of earlier
    revisions a step was found at among them."""
    with session_scope(database_url) as session:
        lock_revision(session, revision_id)
        began = utcnow()
        seen = inputs_seen(session, [revision_id])  # before the samples: see `analysed`
        judged = judge_revision(session, revision_id)
        if judged is not None:
            store(session, session.get_one(Revision, revision_id), judged.rows, rerun=True)
        # its samples gone (None): its stored results stand, as analysed
        mark_analysed(session, seen, began)
        if judged is None:
            return None
    log.info(
        "revision %s: %d series compared, %d flagged",
        revision_id,
        len(judged.changes),
        sum(change.flagged for change in judged.changes),
    )
    return judged
