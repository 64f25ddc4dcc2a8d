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
CPU time), so a change the pairs confirm in references is dropped when the same pairs moved its
CPU time (where it was measured) by less than `HOLD_SHARE` of what they moved it in references,
each the median of the pairs: +5.1 % against +24.1 % there. Not when the CPU time's move is
merely within its own noise: in the loaded part of a later run, CPU +30 % found at its revision
moved +36.6 % and +10.1 % in CPU time (+31.0 % and +37.1 % in references) under a bar of +42.4 %
that its noisy baseline set, and was dropped so; a veto needs the reference to have made the
change, not the CPU time to be too noisy to confirm it.
"""

from __future__ import annotations

import math

import numpy as np
from redline.detect.confirmation import DROPPED, HELD, HOLD_SHARE, Hold, pair_moves
from redline.recording.driver import CPU_PER_OP, CPU_REFS_PER_OP
from redline.server.models import Detection, Series
from redline.server.services.results import beside
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
) -> Hold:
    """``found`` (the pairs' verdict on the detection's series), or `DROPPED` where it held in
    units of the host's reference and the same pairs moved the CPU time per unit of work by less
    than `HOLD_SHARE` of that, the flagged way (medians of the pairs)."""
    series = session.get_one(Series, detection.series_id)
    if found.state != HELD or series.counter != CPU_REFS_PER_OP:
        return found
    raw = beside(session, series, CPU_PER_OP)
    baseline = detection.baseline_revision_id
    if raw is None or baseline is None:
        return found
    in_refs = pair_moves(pair_values(values, series.id, pairs, baseline, candidate))
    in_time = pair_moves(pair_values(values, raw, pairs, baseline, candidate))
    if not in_refs or not in_time:
        return found  # not measured there: the reference's verdict stands
    sign = 1.0 if detection.direction == "increase" else -1.0
    refs, time = float(np.median(in_refs)), float(np.median(in_time))
    if sign * time >= HOLD_SHARE * sign * refs:
        return found
    moved = ", ".join(f"{100 * move:+.1f} %" for move in in_time)
    return Hold(
        DROPPED,
        f"{REFERENCE_ONLY}moved {100 * time:+.1f} % in these pairs ({moved}), less than "
        f"{HOLD_SHARE:.0%} of its {100 * refs:+.1f} % in units of the host's reference work, where "
        # not "confirmed" inside a verdict that is not (a new user's puzzle)
        f"it showed in {found.reason.removeprefix('confirmed by ')}: the reference moved, not "
        "the code",
        found.kept,
    )
