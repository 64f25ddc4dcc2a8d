"""Ingestion: one execution's MCAP recording -> series, summaries (Postgres) and samples (Parquet).

Idempotent: running it again for the same execution replaces what the last run wrote (two runs
for one execution take turns on its job row), so a lost or doubled queue message is harmless:
`stale_uploads` finds the executions whose ingestion never happened, for the periodic re-queue.
"""

from __future__ import annotations

import logging
import os
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from redline.recording import SeriesKey, read_recording
from redline.server.db import session_scope
from redline.server.models import Execution, Job, JobState, Revision, Series, Summary, utcnow
from redline.worker.detection import samples_path, successor_with_data
from sqlalchemy import delete, select, update
from sqlalchemy.dialects.postgresql import insert
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)

QUANTILES = {"p5": 5, "p25": 25, "p50": 50, "p75": 75, "p95": 95}
#: the quantile sketch: 32 evenly spaced levels, mid-bucket (1/64, 3/64, ... 63/64); enough to
#: redraw the distribution and to compare it once the raw samples are pruned
SKETCH_LEVELS = (np.arange(32) + 0.5) / 32
#: how long a job may stay `uploaded` (stored, not ingested) before its ingestion is queued again
STALE_UPLOAD = timedelta(minutes=10)


def summarize(values: np.ndarray) -> dict[str, Any] | None:
    """n, mean, std (population), min, max, the quantiles and the sketch of one series.

    Only finite samples count (``n`` is how many there were); None when there is none. The raw
    samples, NaN and infinities included, stay in the Parquet table for detection to judge.
    """
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    stats: dict[str, Any] = {
        "n": int(values.size),
        "mean": float(values.mean()),
        "std": float(values.std()),
        "min": float(values.min()),
        "max": float(values.max()),
    }
    for name, value in zip(QUANTILES, np.percentile(values, list(QUANTILES.values())), strict=True):
        stats[name] = float(value)
    stats["sketch"] = [float(v) for v in np.quantile(values, SKETCH_LEVELS)]
    return stats


def _series_ids(session: Session, component_id: int, keys: list[SeriesKey]) -> dict[SeriesKey, int]:
    """Create the series the recording names that do not exist yet; return every key's id."""
    if keys:
        rows = [
            dict(
                component_id=component_id,
                case=k.case,
                phase=k.phase,
                params=k.params,
                process=k.process,
                counter=k.counter,
            )
            for k in keys
        ]
        session.execute(insert(Series).values(rows).on_conflict_do_nothing())
    known = session.scalars(select(Series).where(Series.component_id == component_id))
    by_key = {SeriesKey(s.case, s.phase, s.params, s.process, s.counter): s.id for s in known}
    return {key: by_key[key] for key in keys}


def _write_samples(
    path: Path, ids: dict[SeriesKey, int], samples: dict[SeriesKey, list[float]]
) -> None:
    series = np.concatenate(
        [np.full(len(samples[k]), ids[k], dtype=np.int64) for k in ids]
        or [np.empty(0, dtype=np.int64)]
    )
    values = np.concatenate(
        [np.asarray(samples[k], dtype=np.float64) for k in ids] or [np.empty(0, dtype=np.float64)]
    )
    partial = path.with_suffix(".part")
    pq.write_table(pa.table({"series_id": series, "value": values}), partial)
    os.replace(partial, path)


def _ingest(session: Session, execution: Execution) -> None:
    job = session.get_one(Job, execution.job_id, with_for_update=True)  # one run at a time
    recording = read_recording(execution.recording_path, strict=True)
    samples = {key: values for key, values in recording.series_samples().items() if values}
    revision = session.get_one(Revision, execution.revision_id)
    ids = _series_ids(session, revision.component_id, sorted(samples))
    session.execute(delete(Summary).where(Summary.execution_id == execution.id))
    summaries = {key: summarize(np.asarray(samples[key], dtype=np.float64)) for key in ids}
    session.add_all(
        Summary(execution_id=execution.id, series_id=ids[key], **stats)
        for key, stats in summaries.items()
        if stats is not None
    )
    _write_samples(samples_path(execution.recording_path), ids, samples)
    job.state, job.reason = JobState.done, ""


def _fail(database_url: str, execution_id: int, reason: str) -> None:
    with session_scope(database_url) as session:
        execution = session.get(Execution, execution_id)
        if execution is not None:
            job = session.get_one(Job, execution.job_id)
            job.state, job.reason = JobState.failed, reason


def ingest_execution(database_url: str, execution_id: int) -> list[int]:
    """Ingest one execution in one transaction and mark its job done.

    Returns the revisions whose changes should be detected now: the execution's own, and the
    next revision (by sort key) that already has data, whose baseline this one may have become.
    A bad recording (`RecordingError`, or another ValueError from its data) marks the job
    failed with the reason and is raised again. Any other error (a database or broker outage,
    storage) is raised leaving the job `uploaded`, for the task's retries or the periodic
    re-queue to ingest it later: a passing outage must not fail a good recording.
    """
    try:
        with session_scope(database_url) as session:
            execution = session.get(Execution, execution_id)
            if execution is None:
                log.warning("execution %s no longer exists; nothing to ingest", execution_id)
                return []
            _ingest(session, execution)
            later = successor_with_data(session, execution.revision_id)
            revisions = [execution.revision_id] + ([later] if later is not None else [])
            session.execute(
                update(Revision).where(Revision.id.in_(revisions)).values(analyzed_at=None)
            )
            return revisions
    except ValueError as exc:  # RecordingError is one
        _fail(database_url, execution_id, f"ingest failed: {exc}")
        raise


def stale_uploads(
    session: Session, older_than: timedelta = STALE_UPLOAD, limit: int = 500
) -> list[int]:
    """Executions whose job has been `uploaded` for longer than ``older_than``, oldest first.

    Their ingestion was never queued (broker down at upload) or was lost; ingestion is
    idempotent, so queueing one again that is merely slow costs a repeat, nothing more.
    """
    return list(
        session.scalars(
            select(Execution.id)
            .join(Job, Job.id == Execution.job_id)
            .where(
                Job.state == JobState.uploaded,
                Job.updated < utcnow() - older_than,
                Execution.pruned_at.is_(None),
            )
            .order_by(Job.updated, Execution.id)
            .limit(limit)
        )
    )
