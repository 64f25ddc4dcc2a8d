"""Aggregation of one test's per-series (or per-rule, per-cluster) scores into one.

Wienke & Wrede (2016, section 5) combine the many scores a method returns for one test with
min, max and mean, and report ROC-AUC for each; Redline offers the same three.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
from redline.detect.methods import Detector
from redline.detect.result import CHANGE, NO_CHANGE, Detection, direction_of, not_enough

AGGREGATIONS: dict[str, Callable[[np.ndarray], float]] = {
    "min": lambda scores: float(np.min(scores)),
    "max": lambda scores: float(np.max(scores)),
    "mean": lambda scores: float(np.mean(scores)),
}


def aggregate_scores(scores: Sequence[float] | np.ndarray, how: str) -> float:
    """min, max or mean of the scores; raises ValueError for another name (a caller's error)."""
    if how not in AGGREGATIONS:
        raise ValueError(f"aggregation must be one of {sorted(AGGREGATIONS)}, not {how!r}")
    return AGGREGATIONS[how](np.asarray(scores, dtype=np.float64))


def aggregate(detections: Sequence[Detection], how: str = "max", method: str = "") -> Detection:
    """One test's verdict from its series' detections.

    The score aggregates the decided series' scores; the test shows a change when any series
    does; the p-value is the smallest one, Bonferroni-corrected for the number of series
    tested. Series without enough data are named in ``reason``; a test where no series could
    be decided is itself "not enough data".
    """
    name = method or (detections[0].method if detections else "")
    decided = [d for d in detections if d.decided]
    skipped = [d.reason for d in detections if not d.decided]
    if not decided:
        why = "; ".join(sorted(set(skipped))) or "no series to compare"
        return not_enough(name, why)
    flagged = [d for d in decided if d.flagged]
    pool = flagged or decided
    effect = max((d.effect for d in pool), key=abs)
    p_values = [d.p_value for d in decided if d.p_value is not None]
    p_value = min(1.0, min(p_values) * len(p_values)) if p_values else None
    reason = f"{len(skipped)} of {len(detections)} series had not enough data" if skipped else ""
    return Detection(
        method=name,
        verdict=CHANGE if flagged else NO_CHANGE,
        score=aggregate_scores([d.score for d in decided], how),
        p_value=p_value,
        effect=effect,
        direction=direction_of(effect),
        reason=reason,
        parts=tuple(d.score for d in decided),
    )


def compare_test(
    detector: Detector,
    baselines: Mapping[str, object],
    candidates: Mapping[str, object],
    how: str = "max",
) -> Detection:
    """Compare every series of a candidate execution with its baseline, then aggregate.

    A series the baseline lacks gets "missing baseline"; it does not silently vanish.
    """
    detections = [
        detector.compare(baselines.get(series), values) for series, values in candidates.items()
    ]
    return aggregate(detections, how=how, method=detector.name)
