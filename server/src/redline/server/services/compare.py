"""Compare two revisions of a component, series by series (two-sample KS, relative change).

Samples come from the Parquet tables beside the recordings; where retention pruned them, the
summaries' quantile sketches stand in (and the comparison says it is not exact).
"""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np
import pyarrow.parquet as pq
from redline.detect.ks import ks
from redline.detect.summary import describe
from redline.server.models import Execution, Series, Summary
from redline.server.schemas.results import Comparison, SeriesComparison, Statistics
from redline.server.services.components import get_component, get_revision
from redline.server.services.results import series_ref
from redline.server.storage import not_judged, samples_path
from sqlalchemy import select
from sqlalchemy.orm import Session


def revision_samples(session: Session, revision_id: int) -> tuple[dict[int, np.ndarray], bool]:
    """Pooled samples per series id of the revision, and whether all were raw (not sketches)."""
    parts: dict[int, list[np.ndarray]] = defaultdict(list)
    exact = True
    executions = session.scalars(
        select(Execution).where(Execution.revision_id == revision_id).order_by(Execution.id)
    )
    for execution in executions:
        path = samples_path(execution.recording_path)
        if execution.pruned_at is None and path.exists():
            table = pq.read_table(path)
            if not_judged(table) is not None:  # the component took no part: nothing to compare
                continue
            for series_id, values in table.to_pandas().groupby("series_id")["value"]:
                parts[int(series_id)].append(values.to_numpy())
            continue
        for summary in session.scalars(select(Summary).where(Summary.execution_id == execution.id)):
            exact = False
            stand_in = summary.sketch or [
                summary.p5,
                summary.p25,
                summary.p50,
                summary.p75,
                summary.p95,
            ]
            parts[summary.series_id].append(np.asarray(stand_in, dtype=np.float64))
    return {sid: np.concatenate(chunks) for sid, chunks in parts.items()}, exact


def statistics(values: np.ndarray) -> Statistics:
    return Statistics(**describe(values))


def compare(session: Session, component_name: str, base: str, candidate: str) -> Comparison:
    """Every series both revisions measured: their statistics, relative change and KS test."""
    component = get_component(session, component_name)
    before = get_revision(session, component, base)
    after = get_revision(session, component, candidate)
    base_samples, base_exact = revision_samples(session, before.id)
    cand_samples, cand_exact = revision_samples(session, after.id)
    common = sorted(set(base_samples) & set(cand_samples))
    series = {s.id: s for s in session.scalars(select(Series).where(Series.id.in_(common)))}
    rows = []
    for series_id in common:
        old, new = base_samples[series_id], cand_samples[series_id]
        result = ks(old, new)
        rows.append(
            SeriesComparison(
                series=series_ref(series[series_id]),
                baseline=statistics(old),
                candidate=statistics(new),
                change=result.effect if math.isfinite(result.effect) else None,
                ks_statistic=result.statistic,
                p_value=result.p_value,
                exact=base_exact and cand_exact,
            )
        )
    return Comparison(component=component.name, base=base, candidate=candidate, series=rows)
