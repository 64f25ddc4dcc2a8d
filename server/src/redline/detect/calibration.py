"""How much a series moves between executions of the same code, and what that means for the
changes Redline can see: the figure a team needs before trusting a threshold.

For each judged series, one value per execution (the median of its samples, as the default
detector `ExecutionShift` reduces executions), then:

- ``cv``: the spread between executions, standard deviation over mean;
- ``spread``: the robust relative spread `ExecutionShift` judges against,
  ``max(1.4826 MAD / |median|, rel_scale)``;
- ``detectable``: the smallest relative change `ExecutionShift` flags at the service's defaults
  (which confirm a flag, so at its ``confirmed_threshold``), with the
  suite's executions per revision judged against a full baseline (``baseline_values``):
  ``max(min_effect, threshold * spread * sqrt(1/n_candidate + 1/n_baseline))``;
- ``needed``: the executions per revision for a target change (None: out of reach at the
  defaults, because the target is under ``min_effect`` or the baseline's own uncertainty
  already exceeds it).

Pure: values in, figures out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from redline.detect.execution_shift import ExecutionShift
from redline.recording import SeriesKey

#: The 1.4826 * MAD scale of a normal distribution's standard deviation.
MAD_TO_SD = 1.4826


@dataclass(frozen=True)
class Calibrated:
    key: SeriesKey
    executions: int
    median: float
    cv: float
    spread: float
    detectable: float
    needed: int | None


def _robust_spread(values: np.ndarray, rel_scale: float) -> float:
    middle = float(np.median(values))
    mad = float(np.median(np.abs(values - middle)))
    return max(MAD_TO_SD * mad / abs(middle), rel_scale) if middle else math.inf


def calibrate_series(
    key: SeriesKey,
    values: Sequence[float],
    per_revision: int,
    target: float,
    detector: ExecutionShift | None = None,
) -> Calibrated | None:
    """One series' figures from its execution values; None with fewer than two finite ones."""
    judge = detector or ExecutionShift().confirmed()  # the service's defaults confirm flags
    clean = np.asarray([v for v in values if math.isfinite(v)], dtype=np.float64)
    if clean.size < 2:
        return None
    mean = float(clean.mean())
    cv = float(clean.std(ddof=1) / abs(mean)) if mean else math.inf
    spread = _robust_spread(clean, judge.rel_scale)
    uncertainty = math.sqrt(1 / per_revision + 1 / judge.baseline_values)
    detectable = max(judge.min_effect, judge.threshold * spread * uncertainty)
    needed = None
    if target >= judge.min_effect and math.isfinite(spread):
        room = (target / (judge.threshold * spread)) ** 2 - 1 / judge.baseline_values
        needed = math.ceil(1 / room) if room > 0 else None
    return Calibrated(
        key=key,
        executions=int(clean.size),
        median=float(np.median(clean)),
        cv=cv,
        spread=spread,
        detectable=detectable,
        needed=needed,
    )


def calibrate(
    values: Mapping[SeriesKey, Sequence[float]], per_revision: int, target: float = 0.05
) -> list[Calibrated]:
    """Every series with at least two execution values, the noisiest first."""
    found = [calibrate_series(key, series, per_revision, target) for key, series in values.items()]
    return sorted((c for c in found if c is not None), key=lambda c: -c.spread)
