"""One method's verdict on one series in the service: the detector, then the counter's floor.

Pure (no database). Whatever the data or the detector does, the answer is a `Detection`: bad
input is "not enough data" with the reason (the detectors' own checks), and a detector that
fails is logged and answered "not enough data" naming the error, so one series cannot stop the
analysis of the others.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from redline.detect.floors import absolute_floor
from redline.detect.methods import Detector, KolmogorovSmirnov
from redline.detect.result import METHOD_FAILED, NO_CHANGE, Detection, not_enough

log = logging.getLogger(__name__)

#: how the reason of a series KS saw apart but could not call begins (`too_few`)
TOO_FEW = "too few values to decide:"


def judge_series(
    detector: Detector,
    counter: str,
    baseline: np.ndarray | None,
    candidate: np.ndarray | None,
    missing: str = "missing baseline",
) -> Detection:
    """``detector`` on one series, a change also needing the counter's absolute floor.

    ``baseline`` None means there is none; ``missing`` then says why. ``candidate`` None: the
    revision has no samples of the series.
    """
    if candidate is None:
        return not_enough(detector.name, "no samples of this series in the revision")
    if baseline is None:
        return not_enough(detector.name, missing)
    try:
        found = detector.compare(baseline, candidate)
    except Exception as exc:  # a detector bug must not lose the other series' verdicts
        log.exception("%s failed on %s", detector.name, counter)
        return not_enough(detector.name, f"{METHOD_FAILED}: {type(exc).__name__}: {exc}")
    if isinstance(detector, KolmogorovSmirnov):
        found = too_few(detector, found, counter, baseline, candidate) or found
    return floored(found, counter, baseline, candidate)


def too_few(
    detector: KolmogorovSmirnov,
    found: Detection,
    counter: str,
    baseline: np.ndarray,
    candidate: np.ndarray,
) -> Detection | None:
    """ "Not enough data" where KS saw the sides apart by more than its floors but could not
    call it: with one value an execution (CPU per unit of work) and 3 executions a side, the
    smallest p KS can give is 0.1 (a trial's tripled work per message passed `redline compare`
    as "no change"; a third trial's server said "no change" at +100 %, D = 1)."""
    if (
        found.flagged
        or found.score != 1.0  # the sides overlap: KS's "no change" stands (nearly always)
        or abs(found.effect or 0.0) < detector.min_effect
    ):
        return None
    n, m = np.asarray(baseline).size, np.asarray(candidate).size
    smallest_p = 2 / math.comb(n + m, n)
    moved = abs(float(np.mean(candidate)) - float(np.mean(baseline)))
    if smallest_p < detector.alpha or moved < absolute_floor(counter):
        return None
    return not_enough(
        detector.name,
        f"{TOO_FEW} the {n} and {m} values do not overlap (effect {found.effect:+.1%}), but "
        f"with so few KS cannot reach p < {detector.alpha:g} (its smallest p here: "
        f"{smallest_p:.2g}): record more executions a side (5 and 5 suffice)",
    )


def floored(
    found: Detection, counter: str, baseline: np.ndarray, candidate: np.ndarray
) -> Detection:
    """``found``, or "no change" when its change of the mean is below the counter's absolute
    floor (`redline.detect.floors`)."""
    if not found.flagged:
        return found
    floor = absolute_floor(counter)
    moved = abs(float(np.mean(candidate)) - float(np.mean(baseline)))
    if moved >= floor:
        return found
    return Detection(
        method=found.method,
        verdict=NO_CHANGE,
        score=found.score,
        p_value=found.p_value,
        effect=found.effect,
        direction=found.direction,
        reason=f"change of the mean {moved:.3g} below the absolute floor {floor:g} of {counter}",
        parts=found.parts,
    )
