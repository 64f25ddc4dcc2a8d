"""One method's verdict on one series in the service: the detector, then the counter's floor.

Pure (no database). Whatever the data or the detector does, the answer is a `Detection`: bad
input is "not enough data" with the reason (the detectors' own checks), and a detector that
fails is logged and answered "not enough data" naming the error, so one series cannot stop the
analysis of the others.
"""

from __future__ import annotations

import logging

import numpy as np
from redline.detect.floors import absolute_floor
from redline.detect.methods import Detector
from redline.detect.result import METHOD_FAILED, NO_CHANGE, Detection, not_enough

log = logging.getLogger(__name__)


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
    return floored(found, counter, baseline, candidate)


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
