"""The two-sample Kolmogorov-Smirnov test on the D statistic (Wienke & Wrede's first method).

A pure function over numpy arrays: no database, no I/O.
"""

from __future__ import annotations

import functools
import inspect
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

#: p-value below which the two samples are taken to come from different distributions.
DEFAULT_ALPHA = 0.01
#: smallest relative change of the mean worth reporting (the design's effect-size floor).
DEFAULT_MIN_EFFECT = 0.10


#: scipy's ks_2samp without its NaN-policy and broadcasting wrappers (functools.wraps keeps the
#: function as ``__wrapped__``): 6.5x faster on the 1-D finite arrays this module passes, the
#: same statistic and p-value (tests/test_detect_ks.py compares it with the public function).
@functools.cache
def _ks_2samp() -> Callable[..., Any]:
    from scipy import stats  # where it runs: see `redline.detect`

    return inspect.unwrap(stats.ks_2samp)


# scipy falls back from the exact p-value to the asymptotic one on large or tied samples, and
# says so on every such call: a user's console filled with it (the p-value stays right)
warnings.filterwarnings(
    "ignore", message="ks_2samp: Exact calculation unsuccessful", category=RuntimeWarning
)


@dataclass(frozen=True)
class KsResult:
    statistic: float  # D: the largest distance between the two empirical CDFs, 0..1
    p_value: float
    effect: float  # (mean(candidate) - mean(baseline)) / |mean(baseline)|
    flagged: bool


def relative_effect(baseline: np.ndarray, candidate: np.ndarray) -> float:
    """Relative change of the mean; 0 when both means are 0, +-inf when only the baseline's is."""
    before, after = float(np.mean(baseline)), float(np.mean(candidate))
    if before == 0.0:
        return 0.0 if after == 0.0 else math.copysign(math.inf, after)
    return (after - before) / abs(before)


def ks(
    baseline: np.ndarray,
    candidate: np.ndarray,
    *,
    alpha: float = DEFAULT_ALPHA,
    min_effect: float = DEFAULT_MIN_EFFECT,
    min_change: float = 0.0,
) -> KsResult:
    """Compare a candidate revision's samples of one series with its baseline's.

    ``flagged`` is true when the KS test rejects equality (``p_value < alpha``, default 0.01)
    *and* the mean moved by at least ``min_effect`` relative to the baseline (default 0.10,
    i.e. 10 %) *and* by at least ``min_change`` in the counter's own unit (default 0; see
    `redline.detect.floors`), so that statistically clear but tiny changes stay quiet.
    Raises ValueError when either sample is empty.
    """
    base = np.asarray(baseline, dtype=np.float64).ravel()
    cand = np.asarray(candidate, dtype=np.float64).ravel()
    if base.size == 0 or cand.size == 0:
        raise ValueError(
            "both samples need at least one value "
            f"(baseline has {base.size}, candidate {cand.size})"
        )
    result = _ks_2samp()(base, cand)
    statistic, p_value = float(result.statistic), float(result.pvalue)
    effect = relative_effect(base, cand)
    change = abs(float(np.mean(cand)) - float(np.mean(base)))
    flagged = p_value < alpha and abs(effect) >= min_effect and change >= min_change
    return KsResult(statistic=statistic, p_value=p_value, effect=effect, flagged=flagged)
