"""Compare two revisions of a component, series by series (two-sample KS, relative change).

Either side may be a range, ``a..b``: the samples of every revision from ``a`` to ``b`` in
sort-key order (both included, at most `MAX_RANGE`), pooled. A title that exists is always that
revision, even one with ``..`` in it. Samples come from the Parquet tables beside the
recordings; where retention pruned them, the summaries' quantile sketches stand in (and the
comparison says it is not exact).
"""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np
import pyarrow.parquet as pq
from redline.detect.counters import judged_among
from redline.detect.ks import ks
from redline.detect.summary import describe
from redline.server.models import Component, Execution, Revision, Series, Summary, revision_place
from redline.server.schemas.regressions import DetectionOut
from redline.server.schemas.results import Comparison, SeriesComparison, Statistics
from redline.server.services.components import get_component, get_revision
from redline.server.services.detection_config import component_config
from redline.server.services.errors import BadRequest
from redline.server.services.regressions import list_detections
from redline.server.services.results import series_ref
from redline.server.storage import not_judged, samples_path
from sqlalchemy import literal, select, tuple_
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


#: the most revisions one side of a comparison pools (each execution's samples are read)
MAX_RANGE = 50


def split_range(spec: str) -> tuple[str, str]:
    """``a..b`` as (a, b); a title as (title, "")."""
    first, dots, last = spec.partition("..")
    return (first, last) if dots and first and last else (spec, "")


def revision_range(session: Session, component: Component, spec: str, side: str) -> list[Revision]:
    """The revision titled ``spec``, or those of the range ``a..b`` in sort-key order;
    `NotFound` naming a title the component does not have, `BadRequest` naming ``side`` for a
    range past `MAX_RANGE` revisions."""
    first, last = split_range(spec)
    exact = session.scalar(
        select(Revision).where(Revision.component_id == component.id, Revision.title == spec)
    )
    if exact is not None or not last:
        return [exact or get_revision(session, component, spec)]
    ends = sorted(
        (get_revision(session, component, first), get_revision(session, component, last)),
        key=lambda r: (r.order_key, r.id),
    )
    low, high = (tuple_(literal(r.order_key, Revision.order_key.type), literal(r.id)) for r in ends)
    key = revision_place()
    found = list(
        session.scalars(
            select(Revision)
            .where(Revision.component_id == component.id, key >= low, key <= high)
            .order_by(Revision.order_key, Revision.id)
            .limit(MAX_RANGE + 1)
        )
    )
    if len(found) > MAX_RANGE:
        raise BadRequest(f"{side}: {spec!r} spans more than {MAX_RANGE} revisions")
    return found


def pooled_samples(
    session: Session, revisions: list[Revision]
) -> tuple[dict[int, np.ndarray], bool]:
    """`revision_samples` of several revisions, pooled per series."""
    parts: dict[int, list[np.ndarray]] = defaultdict(list)
    exact = True
    for revision in revisions:
        samples, whole = revision_samples(session, revision.id)
        exact = exact and whole
        for series_id, values in samples.items():
            parts[series_id].append(values)
    return {sid: np.concatenate(chunks) for sid, chunks in parts.items()}, exact


def candidate_verdicts(
    session: Session, component_name: str, candidate: str
) -> dict[int, dict[str, DetectionOut]]:
    """Per series, each method's stored verdict of the candidate revision (against its own
    baseline): what the compare page shows beside the two sides; none for a range."""
    found: dict[int, dict[str, DetectionOut]] = defaultdict(dict)
    if split_range(candidate)[1]:
        component = get_component(session, component_name)
        exact = select(Revision.id).where(
            Revision.component_id == component.id, Revision.title == candidate
        )
        if session.scalar(exact) is None:
            return found
    for detection in list_detections(session, component_name, revision=candidate, limit=10_000)[0]:
        found[detection.series.id][detection.method] = detection
    return found


def compare(session: Session, component_name: str, base: str, candidate: str) -> Comparison:
    """Every series both sides measured: their statistics, relative change and KS test; each
    side a revision or a range ``a..b`` of them, pooled."""
    component = get_component(session, component_name)
    before = revision_range(session, component, base, "base")
    after = revision_range(session, component, candidate, "candidate")
    if both := sorted({r.title for r in before} & {r.title for r in after}):
        # a trial's baseline range held its candidate: a comparison with itself, shown as one
        raise BadRequest(
            f"base and candidate share {', '.join(both[:5])}: a revision compared with itself "
            "shows no change; give a base that ends before the candidate"
        )
    base_samples, base_exact = pooled_samples(session, before)
    cand_samples, cand_exact = pooled_samples(session, after)
    common = sorted(set(base_samples) & set(cand_samples))
    series = {s.id: s for s in session.scalars(select(Series).where(Series.id.in_(common)))}
    config = component_config(session, component.id)
    context = config.context_counters
    # judged as the series API says: by the component's methods, whichever CPU figure each judges
    judged_ids = {s.id for s in judged_among(series.values(), context, config.levels)}
    rows = []
    for series_id in common:
        old, new = base_samples[series_id], cand_samples[series_id]
        result = ks(old, new)
        rows.append(
            SeriesComparison(
                series=series_ref(series[series_id], context, judged_ids),
                baseline=statistics(old),
                candidate=statistics(new),
                change=result.effect if math.isfinite(result.effect) else None,
                ks_statistic=result.statistic,
                p_value=result.p_value,
                exact=base_exact and cand_exact,
            )
        )
    return Comparison(
        component=component.name,
        base=base,
        candidate=candidate,
        base_revisions=[r.title for r in before],
        candidate_revisions=[r.title for r in after],
        series=rows,
    )
