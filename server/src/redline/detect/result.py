"""What every detector returns, and the input checks that turn bad data into "not enough data".

A detector never raises on data and never answers a silent "no change": bad input becomes a
`Detection` whose verdict is ``NOT_ENOUGH_DATA`` and whose ``reason`` names what is missing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

CHANGE = "change"
NO_CHANGE = "no change"
NOT_ENOUGH_DATA = "not enough data"


@dataclass(frozen=True)
class Detection:
    """One detector's answer for one baseline/candidate comparison.

    ``score`` is 0 when there was not enough data (the detector abstained), so ranking metrics
    treat an abstention as "least likely a change". ``parts`` holds the per-counter, per-cluster
    or per-rule scores that ``score`` aggregates.
    """

    method: str
    verdict: str
    score: float = 0.0
    p_value: float | None = None
    effect: float = 0.0  # (mean(candidate) - mean(baseline)) / |mean(baseline)|
    direction: str = "none"  # "increase", "decrease" or "none"
    reason: str = ""
    parts: tuple[float, ...] = field(default=())

    @property
    def flagged(self) -> bool:
        return self.verdict == CHANGE

    @property
    def decided(self) -> bool:
        return self.verdict != NOT_ENOUGH_DATA


#: how the reason of a baseline with too few values begins
SHORT_BASELINE = "too few samples: baseline has"


def not_enough(method: str, reason: str) -> Detection:
    return Detection(method=method, verdict=NOT_ENOUGH_DATA, reason=reason)


#: how the "not enough data" reason of a method that raised begins (`redline.detect.verdict`)
METHOD_FAILED = "method failed"

#: why a series the newest earlier revision measured has no verdict of this one
NOT_MEASURED_MARK = "not measured in this revision, though the revision before measured it"
#: (what a stored reason is known by: `NOT_MEASURED_MARK`, the same in reasons stored before
#: its explanation was worded as now)
NOT_MEASURED = (
    f"{NOT_MEASURED_MARK} (a phase or action of the test removed or renamed, or a driver "
    "report missing)"
)

#: how the "not enough data" reasons begin that more history lifts
HISTORY_REASONS = ("missing baseline", "too few samples: baseline")


def waits_for_history(reason: str) -> bool:
    """Whether a "not enough data" reason is one more history will lift (no baseline yet, a
    baseline with too few values), not one it never will (a constant series, NaN)."""
    return reason.startswith(HISTORY_REASONS)


def effect_size(effect: float | None) -> float:
    """How large a flagged change is, to name the largest first: one from zero (no ratio,
    ``None``) is larger than any ratio."""
    return math.inf if effect is None else abs(effect)


def direction_of(effect: float) -> str:
    if effect > 0:
        return "increase"
    if effect < 0:
        return "decrease"
    return "none"


def relative_effects(baseline: np.ndarray, candidate: np.ndarray) -> np.ndarray:
    """Per-counter relative change of the mean (columns of 2-D arrays); 0 when both means are 0."""
    before = np.atleast_1d(np.mean(baseline, axis=0))
    after = np.atleast_1d(np.mean(candidate, axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):
        effects = (after - before) / np.abs(before)
    zero = before == 0
    effects[zero & (after == 0)] = 0.0
    effects[zero & (after != 0)] = np.copysign(math.inf, after[zero & (after != 0)])
    return effects


def largest(effects: np.ndarray) -> float:
    """The effect of largest magnitude, keeping its sign."""
    return float(effects[int(np.argmax(np.abs(effects)))])


def passes_floor(effects: np.ndarray, min_effect: float | np.ndarray) -> np.ndarray:
    """The effect-size floor, per counter: True where |effect| >= that counter's floor.

    ``min_effect`` is one floor for every counter or one per counter, so a noisy counter (say
    memory under a garbage collector) can be given a higher floor than a quiet one.
    """
    floors = np.broadcast_to(np.asarray(min_effect, dtype=np.float64), effects.shape)
    return np.abs(effects) >= floors


def check_samples(
    baseline: object, candidate: object, *, min_baseline: int, min_candidate: int, ndim: int = 1
) -> tuple[np.ndarray, np.ndarray] | str:
    """Both samples as float arrays, or the reason they cannot be compared.

    ``ndim`` is 1 for one series, 2 for samples x counters. The reasons are: missing baseline,
    missing candidate, wrong shape, NaN/inf, too few samples, constant series.
    """
    if baseline is None:
        return "missing baseline"
    if candidate is None:
        return "missing candidate"
    try:
        base = np.asarray(baseline, dtype=np.float64)
        cand = np.asarray(candidate, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        return f"samples are not numeric ({exc})"
    if ndim == 1:
        base, cand = base.ravel(), cand.ravel()
    elif base.ndim == 1 and cand.ndim == 1:
        base, cand = base[:, None], cand[:, None]
    if base.ndim != ndim or cand.ndim != ndim:
        return f"expected {ndim}-D arrays, got baseline {base.ndim}-D and candidate {cand.ndim}-D"
    if ndim == 2 and base.shape[1] != cand.shape[1]:
        return f"baseline has {base.shape[1]} counters, candidate {cand.shape[1]}"
    if base.size == 0:
        return "missing baseline (no samples)"
    for name, values in (("baseline", base), ("candidate", cand)):
        bad = int(np.count_nonzero(~np.isfinite(values)))
        if bad:
            return f"{name} contains NaN/inf ({bad} values)"
    if len(base) < min_baseline:
        return (
            f"{SHORT_BASELINE} {len(base)}, needs {min_baseline}: {min_baseline - len(base)} "
            "short; a change here is looked for again as later revisions are measured"
        )
    if len(cand) < min_candidate:
        return f"too few samples: candidate has {len(cand)}, needs at least {min_candidate}"
    pooled = np.concatenate([base, cand])
    if np.all(np.ptp(pooled, axis=0) == 0):
        return f"constant series: all {len(pooled)} values are equal"
    return base, cand
