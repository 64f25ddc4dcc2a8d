"""What the revision page shows beside the revision's own record: each verdict's baseline and
candidate values, and each execution's duration and disturbed phases.

A verdict's two values are the levels its method compared, of the candidate revision's own
executions and of its baseline's, pooled as the detection pooled them (the newest
``baseline_revisions`` revisions up to its newest baseline revision that measured the series,
`redline.server.services.why`): for KS, whose change is that of the mean, the mean of their
samples pooled; for the other methods, the median of their medians (what `execution_shift`
judges, and what its change is the relative difference of). A trial read a KS row of 9.919e+06
against 9.945e+06 beside a change of -0.6 %: the medians rose where the means fell. They are
read for every verdict of the revision at once, from the revisions just before it, so the page
costs the same however long the history.
"""

from __future__ import annotations

import json
import statistics
from collections import defaultdict
from dataclasses import dataclass

import pyarrow.parquet as pq
from redline.recording import params_name
from redline.server.models import (
    Detection,
    Execution,
    Job,
    Revision,
    Series,
    Summary,
    revision_place,
)
from redline.server.services.executions import run_seconds
from redline.server.services.why import baseline_revisions
from redline.server.storage import DISTURBED, samples_path
from sqlalchemy import select
from sqlalchemy.orm import Session

#: how many revisions before a baseline's newest are read for it, per revision it pools: a
#: series that some of them did not measure is looked up alone (`_one_baseline`)
SLACK = 2


@dataclass(frozen=True)
class ExecutionFacts:
    """What an execution's recording says of its run: how long it took, and the phases the
    host was busy in ("case/phase[params]: why"; None when the samples are gone)."""

    duration_s: float | None
    disturbed: list[str] | None


def execution_facts(session: Session, revision_id: int) -> dict[int, ExecutionFacts]:
    """Per execution of the revision (its own and the confirmation runs of it), its facts."""
    rows = list(
        session.execute(
            select(
                Execution.id, Execution.meta, Execution.recording_path, Execution.pruned_at
            ).where(Execution.revision_id == revision_id)
        )
    )
    busy = {ident: _disturbed_ids(path, pruned is None) for ident, _, path, pruned in rows}
    named = {sid for found in busy.values() if found for sid in found}
    labels = {
        series.id: f"{series.case}/{series.phase}[{params_name(json.loads(series.params))}]"
        for series in session.scalars(select(Series).where(Series.id.in_(named)))
    }
    facts = {}
    for ident, meta, _, _ in rows:
        found = busy[ident]
        phases = None
        if found is not None:  # one line per phase: its counters share the reason
            phases = sorted(
                {f"{labels[sid]}: {why}" for sid, why in found.items() if sid in labels}
            )
        facts[ident] = ExecutionFacts(run_seconds(meta), phases)
    return facts


def _disturbed_ids(recording_path: str, kept: bool) -> dict[int, str] | None:
    """The side table's disturbed series (id -> why), from its schema alone; None without it."""
    path = samples_path(recording_path) if recording_path else None
    if not kept or path is None or not path.is_file():
        return None
    raw = (pq.read_schema(path).metadata or {}).get(DISTURBED)
    return {int(sid): why for sid, why in json.loads(raw).items()} if raw else {}


#: an execution's summary of a series: its median, its number of samples and their mean
Run = tuple[float, int, float]


def _medians(
    session: Session, series_ids: set[int], revision_ids: list[int]
) -> dict[tuple[int, int], list[Run]]:
    """(series, revision) -> the summaries (`Run`) of the revision's own executions of the
    series, those measured while the host was busy left out, as the verdicts leave them out."""
    found: dict[tuple[int, int], list[Run]] = defaultdict(list)
    if not series_ids or not revision_ids:
        return found
    rows = session.execute(
        select(Summary.series_id, Execution.revision_id, Summary.p50, Summary.n, Summary.mean)
        .join(Execution, Execution.id == Summary.execution_id)
        .join(Job, Job.id == Execution.job_id)
        .where(
            Summary.series_id.in_(series_ids),
            Execution.revision_id.in_(revision_ids),
            Job.pair == 0,
            Summary.disturbed.is_(False),
        )
    )
    for series_id, revision_id, p50, n, mean in rows:
        found[(series_id, revision_id)].append((p50, n, mean))
    return found


def _level(runs: list[Run], method: str) -> float | None:
    """What ``method`` compared of these runs: KS the mean of their samples pooled, the others
    the median of their medians."""
    if not runs:
        return None
    if method == "ks":
        counted = sum(n for _, n, _ in runs)
        return sum(n * mean for _, n, mean in runs) / counted if counted else None
    return statistics.median(p50 for p50, _, _ in runs)


def _revisions_up_to(session: Session, newest_id: int, count: int) -> list[int]:
    """The ids of the ``count`` revisions up to ``newest_id`` in sort-key order, newest first."""
    newest = session.get(Revision, newest_id)
    if newest is None:
        return []
    return list(
        session.scalars(
            select(Revision.id)
            .where(
                Revision.component_id == newest.component_id,
                revision_place() <= newest.place,
            )
            .order_by(Revision.order_key.desc(), Revision.id.desc())
            .limit(count)
        )
    )


def _one_baseline(
    session: Session, series_id: int, newest_id: int, count: int, method: str
) -> float | None:
    """A baseline whose series was missing from many revisions: looked up alone (exact)."""
    ids = [r.id for r in baseline_revisions(session, series_id, newest_id, count)]
    medians = _medians(session, {series_id}, ids)
    return _level([v for rid in ids for v in medians.get((series_id, rid), [])], method)


def verdict_values(
    session: Session, revision_id: int
) -> dict[int, tuple[float | None, float | None]]:
    """Per detection of the revision: its baseline's value and the candidate's (None where a
    side has none: a verdict without a baseline)."""
    detections = list(
        session.execute(
            select(
                Detection.id,
                Detection.series_id,
                Detection.baseline_revision_id,
                Detection.baseline_revisions,
                Detection.method,
            ).where(Detection.revision_id == revision_id)
        )
    )
    series_ids = {series_id for _, series_id, _, _, _ in detections}
    own = _medians(session, series_ids, [revision_id])
    groups: dict[tuple[int, int], list[tuple[int, int, str]]] = defaultdict(list)
    for ident, series_id, newest, count, method in detections:
        if newest is not None and count > 0:
            groups[(newest, count)].append((ident, series_id, method))
    baseline: dict[int, float | None] = {}
    for (newest, count), members in groups.items():
        window = _revisions_up_to(session, newest, SLACK * count)
        medians = _medians(session, {sid for _, sid, _ in members}, window)
        for ident, series_id, method in members:
            measured = [rid for rid in window if (series_id, rid) in medians][:count]
            if len(measured) < count and len(window) == SLACK * count:
                baseline[ident] = _one_baseline(session, series_id, newest, count, method)
            else:
                runs = [run for rid in measured for run in medians[(series_id, rid)]]
                baseline[ident] = _level(runs, method)
    return {
        ident: (baseline.get(ident), _level(own.get((series_id, revision_id), []), method))
        for ident, series_id, _, _, method in detections
    }
