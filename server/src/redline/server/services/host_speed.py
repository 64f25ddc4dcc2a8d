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
from collections.abc import Iterable
from statistics import median

from redline.detect.counters import SHARE
from redline.recording.driver import CPU_REFS_PER_OP
from redline.server.models import Detection, Revision, Series
from redline.server.services.why import baseline_revisions, execution_values
from sqlalchemy import select
from sqlalchemy.orm import Session


def at_host_speed(
    session: Session, revision: Revision, charted: Iterable[tuple[Detection, Series]]
) -> dict[int, float]:
    """By detection id, each charted change of a CPU share as its segment's CPU per unit of
    work in units of the host's reference moved (the revision's undisturbed executions against
    those of the revisions the change was judged against), 0 where it fell; a change without
    that figure on both sides is not listed."""
    sized = {}
    for detection, series in charted:
        if series.counter != SHARE:
            continue
        per_unit = session.scalar(
            select(Series.id).where(
                Series.component_id == series.component_id,
                Series.case == series.case,
                Series.phase == series.phase,
                Series.params == series.params,
                Series.process == series.process,
                Series.counter == CPU_REFS_PER_OP,
            )
        )
        if per_unit is None:
            continue
        pooled = baseline_revisions(
            session, series.id, detection.baseline_revision_id, detection.baseline_revisions
        )
        before = _medians(session, per_unit, [r.id for r in pooled])
        after = _medians(session, per_unit, [revision.id])
        if before and after and median(before) > 0:
            moved = median(after) / median(before) - 1
            # the worse way only (a share's is up): a per-unit figure that fell is no worse
            sized[detection.id] = max(0.0, moved)
    return sized


def _medians(session: Session, series_id: int, revision_ids: list[int]) -> list[float]:
    """The series' value in each of the revisions' own executions measured while the host was
    not busy."""
    found = execution_values(session, series_id, revision_ids)
    return [v.median for v in found if not v.disturbed and math.isfinite(v.median)]
