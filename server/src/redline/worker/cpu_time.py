"""A CPU change the confirmation pairs show in units of the host's reference work must show in
the CPU time itself too.

The default method judges a component's CPU per unit of work divided by the host's reference
work timed beside it (`redline.recording.driver.CPU_REFS_PER_OP`), which takes out much of the
host's changing speed between revisions. Within a pair, run back to back, the host's speed
moves little, while the reference has noise of its own: in `bench_verdicts` (2026-12-06) an
unchanged revision's pairs showed +20.6 % and +27.6 % in units of the reference, because the
reference ran 15 % faster in both candidate runs, while its CPU time per operation moved +1.2 %
and +8.9 % (a pair's bar there: +15.7 %); it was a false regression, confirmed by 2 of 2 pairs.
A change of the code moves both (CPU +30 %: +40 % and +18 % in references, +45 % and +38 % in
CPU time), so a change the pairs confirm in references is dropped when its CPU time, judged by
the same pairs against its own noise, does not show it (where it was measured).
"""

from __future__ import annotations

import math

from redline.detect.confirmation import DROPPED, HELD, Hold, pairs_hold
from redline.recording.driver import CPU_PER_OP, CPU_REFS_PER_OP
from redline.server.models import Detection, Series
from redline.worker.confirmation import baseline_noise
from sqlalchemy import select
from sqlalchemy.orm import Session

#: how the reason of a change dropped so begins
REFERENCE_ONLY = "not confirmed: in the CPU time itself the change "

Values = dict[tuple[int, int, int], tuple[float, float]]


def pair_values(
    values: Values, series_id: int, pairs: list[int], baseline: int, candidate: int
) -> list[tuple[float, float]]:
    """The series' (baseline, candidate) medians of each of ``pairs``; NaN where one is missing."""
    nan = (math.nan, math.nan)
    return [
        (
            values.get((series_id, pair, baseline), nan)[0],
            values.get((series_id, pair, candidate), nan)[0],
        )
        for pair in pairs
    ]


def in_cpu_time(
    session: Session,
    detection: Detection,
    found: Hold,
    values: Values,
    pairs: list[int],
    candidate: int,
    wanted: int,
) -> Hold:
    """``found`` (the pairs' verdict on the detection's series), or `DROPPED` where it held in
    units of the host's reference and the pairs did not show it in the CPU time per unit of work
    (`pairs_hold` on that series, with its own baseline's noise)."""
    series = session.get_one(Series, detection.series_id)
    if found.state != HELD or series.counter != CPU_REFS_PER_OP:
        return found
    raw = session.scalar(
        select(Series.id).where(
            Series.component_id == series.component_id,
            Series.case == series.case,
            Series.phase == series.phase,
            Series.params == series.params,
            Series.process == series.process,
            Series.counter == CPU_PER_OP,
        )
    )
    baseline = detection.baseline_revision_id
    if raw is None or baseline is None:
        return found
    shown = pairs_hold(
        pair_values(values, raw, pairs, baseline, candidate),
        detection.direction,
        detection.effect or 0.0,
        wanted,
        baseline_noise(session, detection, raw),
    )
    if shown.state != DROPPED:
        return found  # shown, or not measured there: the reference's verdict stands
    return Hold(
        DROPPED,
        f"{REFERENCE_ONLY}{shown.reason.removeprefix('not confirmed: the change ')}; in units "
        f"of the host's reference work it was {found.reason}: the reference moved, not the code",
        shown.kept,
    )
