"""A charted change of a component's CPU share, sized at the host's speed, for the CI gate.

The charted method (KS) judges the CPU share, whose samples carry the host's speed with them;
the CI gate does not pass a change of `ci_verdict.UNJUDGED_LARGE` or more that the alarm
methods cannot judge yet. Where the same segment also has the CPU per unit of work in units of
the host's reference (`cpu_refs_per_op`, what the default method judges), that figure sizes
the change: a trial's README-only commit, run while the host was 36 % slower than for the
revision before it (the reference took 293 µs against 215), moved the share +50 % and the
CPU per unit of work +10 %, and `redline ci wait` said "undecided" (exit 4).
"""

from __future__ import annotations

import math
from statistics import median

from redline.detect.counters import SHARE
from redline.recording.driver import CPU_REFS_PER_OP
from redline.server.models import Detection, Revision, Series
from redline.server.services.results import beside
from redline.server.services.why import baseline_revisions, execution_values
from sqlalchemy.orm import Session


def at_host_speed(
    session: Session, revision: Revision, detection: Detection, series: Series
) -> float | None:
    """A charted change of a CPU share (``detection`` of ``series`` at ``revision``) as its
    segment's CPU per unit of work in units of the host's reference moved (the revision's
    undisturbed executions against those of the revisions the change was judged against), 0
    where it fell; None for another series, or without that figure on both sides."""
    if series.counter != SHARE:
        return None
    per_unit = beside(session, series, CPU_REFS_PER_OP)
    if per_unit is None:
        return None
    pooled = baseline_revisions(
        session, series.id, detection.baseline_revision_id, detection.baseline_revisions
    )
    before = _medians(session, per_unit, [r.id for r in pooled])
    after = _medians(session, per_unit, [revision.id])
    if not before or not after or median(before) <= 0:
        return None
    # the worse way only (a share's is up): a per-unit figure that fell is no worse
    return max(0.0, median(after) / median(before) - 1)


def _medians(session: Session, series_id: int, revision_ids: list[int]) -> list[float]:
    """The series' value in each of the revisions' own executions measured while the host was
    not busy."""
    found = execution_values(session, series_id, revision_ids)
    return [v.median for v in found if not v.disturbed and math.isfinite(v.median)]
