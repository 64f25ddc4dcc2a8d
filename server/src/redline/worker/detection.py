"""Detection over stored results: each series of a revision against its baseline, every method.

The component's configuration (`redline.detect.config.DetectionConfig`, table
``detection_config``; defaults when absent) names the methods and the baseline: the previous
revision (by sort key) with samples of the series, a window of the previous n such revisions
pooled, or a pinned revision. Every method's verdict on every series is stored as a `Detection`
— "not enough data" with the reason included (no baseline, too few samples, constant, NaN/inf) —
and KS's decided comparisons also as `Change` rows, which the trend charts and
``/api/v1/components/{name}/changes`` show. Flagged detections are then grouped into regressions
(`redline.worker.grouping`). Samples come from the Parquet side tables written at ingestion.
Host-wide series are context, never judged.
"""

from __future__ import annotations

import logging
from collections import defaultdict
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow.parquet as pq
from redline.detect.config import ConfigError, DetectionConfig
from redline.detect.result import NOT_ENOUGH_DATA
from redline.detect.result import Detection as Verdict
from redline.detect.verdict import judge_series
from redline.recording.format import HOST_PROCESS
from redline.server.db import session_scope
from redline.server.models import (
    Change,
    Execution,
    Job,
    JobState,
    Revision,
    Series,
    Summary,
    utcnow,
)
from redline.server.models_regressions import Detection, DetectionConfigRow
from redline.server.storage import samples_path
from redline.worker.grouping import group_revision
from sqlalchemy import Select, delete, func, insert, select, tuple_
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)
METHOD_KS = "ks"
#: the first key of the transaction-scoped advisory lock one revision's detection holds
DETECT_LOCK = 0x5244  # "RD"


def ingested_executions() -> Select[tuple[int]]:
    """Executions whose ingestion finished (their job is done), whatever series they hold: a
    recording whose every sample was NaN has no summary rows but must still be judged."""
    return (select(Execution.id).join(Job, Job.id == Execution.job_id)
            .where(Job.state == JobState.done))


def read_samples(session: Session, revision_id: int) -> tuple[dict[int, np.ndarray], int, int]:
    """Every ingested sample of the revision, all executions pooled, by series id; with how many
    of its ingested executions' side tables were read, and how many there are.

    A side table that is gone (pruned) is left out with a warning: its series then lack data.
    """
    paths = list(session.scalars(
        select(Execution.recording_path).where(Execution.revision_id == revision_id)
        .where(Execution.id.in_(ingested_executions())).order_by(Execution.id)
    ))
    parts: dict[int, list[np.ndarray]] = defaultdict(list)
    read = 0
    for path in paths:
        try:
            table = pq.read_table(samples_path(path)).to_pandas()
        except OSError as exc:
            log.warning("revision %s: samples of %s unreadable: %s", revision_id, path, exc)
            continue
        read += 1
        for series_id, values in table.groupby("series_id")["value"]:
            parts[int(series_id)].append(values.to_numpy())
    samples = {series_id: np.concatenate(chunks) for series_id, chunks in parts.items()}
    return samples, read, len(paths)


def revision_samples(session: Session, revision_id: int) -> dict[int, np.ndarray]:
    """Every ingested and still readable sample of the revision, by series id."""
    return read_samples(session, revision_id)[0]


def _before(revision: Revision):  # noqa: ANN202 - an SQL expression
    return tuple_(Revision.order_key, Revision.id) < (revision.order_key, revision.id)


def successor_with_data(session: Session, revision_id: int) -> int | None:
    """The next revision (by sort key) of the same component that has ingested results."""
    revision = session.get_one(Revision, revision_id)
    return session.scalar(
        select(Revision.id).join(Execution, Execution.revision_id == Revision.id)
        .where(Revision.component_id == revision.component_id,
               tuple_(Revision.order_key, Revision.id) > (revision.order_key, revision.id),
               Execution.id.in_(ingested_executions()))
        .order_by(Revision.order_key, Revision.id).limit(1)
    )


def component_config(session: Session, component_id: int) -> DetectionConfig:
    """The stored configuration, or the defaults (also when the stored one no longer parses)."""
    row = session.get(DetectionConfigRow, component_id)
    try:
        return DetectionConfig.parse(row.config if row else None)
    except ConfigError as exc:
        log.error("component %s: stored detection configuration unusable (%s); defaults used",
                  component_id, exc)
        return DetectionConfig()


def _judged_counters(session: Session, series_ids: list[int]) -> dict[int, str]:
    """Series id → counter, for the component's own processes (host-wide series are context)."""
    rows = session.execute(select(Series.id, Series.counter)
                           .where(Series.id.in_(series_ids), Series.process != HOST_PROCESS))
    return {series_id: counter for series_id, counter in rows}


def _previous_revisions(session: Session, revision: Revision, series_ids: list[int],
                        depth: int) -> dict[int, list[int]]:
    """Per series, the ids of the ``depth`` newest earlier revisions with samples of it."""
    rank = func.dense_rank().over(partition_by=Summary.series_id,
                                  order_by=(Revision.order_key.desc(), Revision.id.desc()))
    ranked = (select(Summary.series_id, Revision.id.label("revision_id"), rank.label("rank"))
              .join(Execution, Execution.id == Summary.execution_id)
              .join(Revision, Revision.id == Execution.revision_id)
              .where(Revision.component_id == revision.component_id,
                     Summary.series_id.in_(series_ids), _before(revision))
              .subquery())
    rows = session.execute(select(ranked.c.series_id, ranked.c.revision_id, ranked.c.rank)
                           .where(ranked.c.rank <= depth).distinct()
                           .order_by(ranked.c.series_id, ranked.c.rank))
    found: dict[int, list[int]] = defaultdict(list)
    for series_id, revision_id, _rank in rows:
        if revision_id not in found[series_id]:
            found[series_id].append(revision_id)
    return found


@dataclass(frozen=True)
class Baseline:
    values: np.ndarray | None
    newest: int | None = None  # the newest baseline revision
    revisions: int = 0
    missing: str = ""


class Baselines:
    """Each series' baseline under the configuration; revisions' samples are read once."""

    def __init__(self, session: Session, revision: Revision, config: DetectionConfig,
                 series_ids: list[int]) -> None:
        self.session, self.config = session, config
        self.cache: dict[int, dict[int, np.ndarray]] = {}
        self.pinned: int | None = None
        if config.baseline == "pinned":
            self.pinned = session.scalar(select(Revision.id).where(
                Revision.component_id == revision.component_id, Revision.title == config.pinned,
                _before(revision)))
            self.previous: dict[int, list[int]] = {}
        else:
            depth = config.window if config.baseline == "window" else 1
            self.previous = _previous_revisions(session, revision, series_ids, depth)

    def samples(self, revision_id: int) -> dict[int, np.ndarray]:
        if revision_id not in self.cache:
            self.cache[revision_id] = revision_samples(self.session, revision_id)
        return self.cache[revision_id]

    def of(self, series_id: int) -> Baseline:
        if self.config.baseline == "pinned":
            if self.pinned is None:
                return Baseline(None, missing=f"missing baseline: pinned revision "
                                f"{self.config.pinned!r} is not an earlier revision")
            ids = [self.pinned]
        else:
            ids = self.previous.get(series_id, [])
        chunks = [self.samples(i)[series_id] for i in ids if series_id in self.samples(i)]
        if not chunks:
            return Baseline(None, missing="missing baseline: no earlier revision has samples "
                            "of this series" if not ids else "missing baseline: the baseline "
                            "revision's samples of this series are unreadable or absent")
        return Baseline(np.concatenate(chunks), ids[0], len(chunks))


def _row(series_id: int, revision_id: int, base: Baseline, verdict: Verdict) -> dict[str, Any]:
    """A `Detection` row, as the values of a bulk insert."""
    effect = verdict.effect if verdict.decided and np.isfinite(verdict.effect) else None
    return dict(series_id=series_id, revision_id=revision_id,
                baseline_revision_id=base.newest, baseline_revisions=base.revisions,
                method=verdict.method, verdict=verdict.verdict, reason=verdict.reason,
                score=float(verdict.score), p_value=verdict.p_value, effect=effect,
                direction=verdict.direction, flagged=verdict.flagged, created=utcnow())


def _ks_change(row: dict[str, Any], verdict: Verdict) -> Change | None:
    """KS's decided comparison as the `Change` the trend charts draw."""
    if row["method"] != METHOD_KS or verdict.verdict == NOT_ENOUGH_DATA or verdict.p_value is None:
        return None
    return Change(series_id=row["series_id"], revision_id=row["revision_id"],
                  baseline_revision_id=row["baseline_revision_id"], method=METHOD_KS,
                  score=verdict.score, p_value=verdict.p_value, effect=verdict.effect,
                  flagged=verdict.flagged, created=row["created"])


def analyze(session: Session, revision: Revision, config: DetectionConfig,
            candidate: dict[int, np.ndarray] | None = None,
            ) -> tuple[list[dict[str, Any]], list[Change]]:
    """Every configured method on every judged series of the revision (nothing stored).

    ``candidate``: the revision's samples, when already read.
    """
    if candidate is None:
        candidate = revision_samples(session, revision.id)
    counters = _judged_counters(session, list(candidate))
    baselines = Baselines(session, revision, config, sorted(counters))
    detectors = config.detectors()
    rows, changes = [], []
    for series_id in sorted(counters):
        base = baselines.of(series_id)
        for detector in detectors:
            verdict = judge_series(detector, counters[series_id], base.values,
                                   candidate[series_id], missing=base.missing)
            rows.append(_row(series_id, revision.id, base, verdict))
            change = _ks_change(rows[-1], verdict)
            if change is not None:
                changes.append(change)
    return rows, changes


def store(session: Session, revision: Revision, rows: list[dict[str, Any]],
          changes: list[Change]) -> None:
    """Replace the revision's detections and KS changes, then regroup its regressions.

    Bulk inserts (no unit of work): 500 series x 2 methods would otherwise spend more time in
    the ORM than in the detectors.
    """
    session.execute(delete(Detection).where(Detection.revision_id == revision.id))
    session.execute(delete(Change).where(Change.revision_id == revision.id,
                                         Change.method == METHOD_KS))
    if rows:
        session.execute(insert(Detection), rows)
    if changes:
        columns = ("series_id", "revision_id", "baseline_revision_id", "method", "score",
                   "p_value", "effect", "flagged", "created")
        session.execute(insert(Change), [{c: getattr(ch, c) for c in columns} for ch in changes])
    group_revision(session, revision)
    revision.analyzed_at = utcnow()


def detect_revision(database_url: str, revision_id: int) -> list[Change]:
    """Run the component's methods on every series of the revision, replacing earlier results.

    Returns KS's changes (a series without a baseline has none; its detections say "not
    enough data: missing baseline"). Detections of one revision take turns (an advisory lock
    for the transaction). A revision with ingested executions none of whose samples can be read
    any more (pruned) keeps its stored results: nothing is not a new verdict.
    """
    with session_scope(database_url) as session:
        session.execute(select(func.pg_advisory_xact_lock(DETECT_LOCK, revision_id)))
        revision = session.get(Revision, revision_id)
        if revision is None:
            return []
        candidate, read, ingested = read_samples(session, revision.id)
        if ingested and not read:
            log.warning("revision %s: the samples of its %d executions are gone (pruned?); "
                        "its stored results are kept", revision_id, ingested)
            return []
        config = component_config(session, revision.component_id)
        rows, changes = analyze(session, revision, config, candidate)
        store(session, revision, rows, changes)
        return changes
