"""Detection over stored results: each series of a revision against its baseline revision.

The baseline of a series is the previous revision (by sort key) of the same component that has
samples of that series. Samples come from the Parquet side tables written at ingestion.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from redline.detect.judge import is_judged, judge
from redline.server.db import session_scope
from redline.server.models import Change, Execution, Revision, Series, Summary, utcnow
from sqlalchemy import delete, select, tuple_
from sqlalchemy.orm import Session

METHOD_KS = "ks"


def samples_path(recording_path: str | Path) -> Path:
    """The Parquet side table (series_id, value) kept beside a recording."""
    return Path(recording_path).with_suffix(".samples.parquet")


def revision_samples(session: Session, revision_id: int) -> dict[int, np.ndarray]:
    """Every ingested sample of the revision, all executions pooled, by series id."""
    paths = session.scalars(
        select(Execution.recording_path).where(Execution.revision_id == revision_id)
        .where(Execution.id.in_(select(Summary.execution_id))).order_by(Execution.id)
    )
    parts: dict[int, list[np.ndarray]] = defaultdict(list)
    for path in paths:
        table = pq.read_table(samples_path(path)).to_pandas()
        for series_id, values in table.groupby("series_id")["value"]:
            parts[int(series_id)].append(values.to_numpy())
    return {series_id: np.concatenate(chunks) for series_id, chunks in parts.items()}


def _before(revision: Revision):  # noqa: ANN202 - an SQL expression
    return tuple_(Revision.order_key, Revision.id) < (revision.order_key, revision.id)


def baseline_revision(session: Session, revision: Revision, series_id: int) -> int | None:
    """The previous revision of the component with samples of this series, or None."""
    return session.scalar(
        select(Revision.id).join(Execution, Execution.revision_id == Revision.id)
        .join(Summary, Summary.execution_id == Execution.id)
        .where(Revision.component_id == revision.component_id, Summary.series_id == series_id,
               _before(revision))
        .order_by(Revision.order_key.desc(), Revision.id.desc()).limit(1)
    )


def successor_with_data(session: Session, revision_id: int) -> int | None:
    """The next revision (by sort key) of the same component that has ingested results."""
    revision = session.get_one(Revision, revision_id)
    return session.scalar(
        select(Revision.id).join(Execution, Execution.revision_id == Revision.id)
        .where(Revision.component_id == revision.component_id,
               tuple_(Revision.order_key, Revision.id) > (revision.order_key, revision.id),
               Execution.id.in_(select(Summary.execution_id)))
        .order_by(Revision.order_key, Revision.id).limit(1)
    )


def _component_counters(session: Session, series_ids: list[int]) -> dict[int, str]:
    """Series id → counter name, for the component's own processes (host-wide series left out:
    they describe the machine during the run, not the component)."""
    rows = session.execute(
        select(Series.id, Series.process, Series.counter).where(Series.id.in_(series_ids))
    )
    return {series_id: counter for series_id, process, counter in rows if is_judged(process)}


def _compare(session: Session, revision: Revision) -> list[Change]:
    candidate = revision_samples(session, revision.id)
    counters = _component_counters(session, list(candidate))
    baselines: dict[int, dict[int, np.ndarray]] = {}
    changes = []
    for series_id, values in sorted(candidate.items()):
        if series_id not in counters:
            continue
        base_id = baseline_revision(session, revision, series_id)
        if base_id is None:
            continue
        if base_id not in baselines:
            baselines[base_id] = revision_samples(session, base_id)
        result = judge(counters[series_id], baselines[base_id][series_id], values)
        changes.append(Change(
            series_id=series_id, revision_id=revision.id, baseline_revision_id=base_id,
            method=METHOD_KS, score=result.statistic, p_value=result.p_value,
            effect=result.effect, flagged=result.flagged,
        ))
    return changes


def detect_revision(database_url: str, revision_id: int) -> list[Change]:
    """Run KS for every series of the revision and replace its earlier KS changes.

    A revision without a predecessor holding the same series stores nothing for that series.
    """
    with session_scope(database_url) as session:
        revision = session.get(Revision, revision_id)
        if revision is None:
            return []
        changes = _compare(session, revision)
        session.execute(
            delete(Change).where(Change.revision_id == revision_id, Change.method == METHOD_KS)
        )
        session.add_all(changes)
        revision.analyzed_at = utcnow()
        return changes
