"""Per-series detectors: the paper's KS test, LNT's Mann-Whitney U and Perfherder's Welch t.

Each detector follows scikit-learn's shape: parameters in ``__init__`` (no work there),
``fit(baseline)`` and ``detect(candidate)`` / ``score(candidate)``, and ``compare(baseline,
candidate)`` for both at once. They are pure functions of numpy arrays: no database, no I/O.
Bad input never raises: it gives a `Detection` with verdict "not enough data" and the reason.
"""

from __future__ import annotations

import inspect
import math
from typing import Any, ClassVar, Protocol, Self

import numpy as np
from redline.detect import ks as ks_module
from redline.detect.result import (
    CHANGE,
    NO_CHANGE,
    Detection,
    check_samples,
    direction_of,
    largest,
    not_enough,
    passes_floor,
    relative_effects,
)


class Levelled(Protocol):
    """What judging a series needs of a method besides its verdict: its name, the level whose
    values it judges (samples, one per execution, one per build) and how many values a
    ``recent`` baseline pools. Every `Detector` is one, and so is `CountRate`."""

    @property
    def name(self) -> str: ...

    @property
    def level(self) -> str: ...

    @property
    def baseline_values(self) -> int: ...


class Detector:
    """Common interface; subclasses set ``name`` and implement ``_detect(base, cand)``."""

    name: ClassVar[str] = ""
    ndim: ClassVar[int] = 1  # 1: one series; 2: samples x counters
    #: "sample": judges samples pooled; "execution": one value per execution (its median)
    level: ClassVar[str] = "sample"
    #: how many values a ``recent`` baseline pools (redline.detect.baseline); 12 is
    #: Perfherder's ``min_back_window``
    baseline_values: int = 12
    min_baseline: int
    min_candidate: int

    def get_params(self) -> dict[str, Any]:
        names = list(inspect.signature(type(self).__init__).parameters)[1:]
        return {name: getattr(self, name) for name in names}

    def params_as_judged(self) -> dict[str, Any]:
        """Its parameters as a verdict keeps them (`redline.server.models.JudgingConfig`): its
        own, and any bar it judges at that none of them holds."""
        return self.get_params()

    def confirmed(self) -> Detector:
        """This detector where re-runs confirm its flags before they are regressions: itself,
        unless a method judges at a bar of its own there
        (`redline.detect.execution_shift.ExecutionShift.confirmed`)."""
        return self

    def fit(self, baseline: object) -> Self:
        self.baseline_ = baseline
        return self

    def detect(self, candidate: object) -> Detection:
        checked = check_samples(
            getattr(self, "baseline_", None),
            candidate,
            min_baseline=self.min_baseline,
            min_candidate=self.min_candidate,
            ndim=self.ndim,
        )
        if isinstance(checked, str):
            return not_enough(self.name, checked)
        return self._detect(*checked)

    def score(self, candidate: object) -> float:
        return self.detect(candidate).score

    def compare(self, baseline: object, candidate: object) -> Detection:
        return self.fit(baseline).detect(candidate)

    def _detect(self, base: np.ndarray, cand: np.ndarray) -> Detection:
        raise NotImplementedError


def _decide(
    name: str,
    score: float,
    p_value: float | None,
    significant: bool,
    effect: float,
    min_effect: float,
) -> Detection:
    """A decided `Detection`: a change needs significance *and* an effect above the floor."""
    above = bool(passes_floor(np.array([effect]), min_effect)[0])
    verdict = CHANGE if significant and above else NO_CHANGE
    reason = ""
    if significant and not above:
        reason = f"|effect| {abs(effect):.3g} below the floor {min_effect}"
    return Detection(
        method=name,
        verdict=verdict,
        score=score,
        p_value=p_value,
        effect=effect,
        direction=direction_of(effect),
        reason=reason,
        parts=(score,),
    )


class KolmogorovSmirnov(Detector):
    """Two-sample Kolmogorov-Smirnov test on one series; the score is D (0..1).

    Wraps `redline.detect.ks.ks` (Wienke & Wrede 2016, section 4.4.3, the paper's best method).
    Defaults from ``ks.py``: change when ``p < alpha = 0.01`` and ``|effect| >= 0.10``.
    ``min_baseline = min_candidate = 2``: with one value a side D is 0 or 1 and says nothing
    about the spread (our choice; KS itself accepts one value).
    """

    name = "ks"

    def __init__(
        self,
        alpha: float = ks_module.DEFAULT_ALPHA,
        min_effect: float = ks_module.DEFAULT_MIN_EFFECT,
        min_baseline: int = 2,
        min_candidate: int = 2,
    ) -> None:
        self.alpha = alpha
        self.min_effect = min_effect
        self.min_baseline = min_baseline
        self.min_candidate = min_candidate

    def _detect(self, base: np.ndarray, cand: np.ndarray) -> Detection:
        result = ks_module.ks(base, cand, alpha=self.alpha, min_effect=self.min_effect)
        return _decide(
            self.name,
            result.statistic,
            result.p_value,
            result.p_value < self.alpha,
            result.effect,
            self.min_effect,
        )


class MannWhitney(Detector):
    """Mann-Whitney U test with LNT's guards; the score is -log10(p).

    Source: LLVM LNT, ``lnt/server/reporting/analysis.py`` (``ComparisonResult``):
    ``confidence_lv = 0.05`` (the U test's significance level), the U test only when both sides
    have at least 4 samples (``len(samples) >= 4 and len(prev_samples) >= 4``), and changes
    below 1 % ignored ("Always ignore percentage changes below 1%"). LNT measures the change
    against the nearest previous sample; here, as for every Redline method, against the mean.
    Where LNT falls back to a stddev rule under 4 samples, this detector says "not enough data".
    """

    name = "mann_whitney"

    def __init__(
        self,
        confidence_lv: float = 0.05,
        min_effect: float = 0.01,
        min_baseline: int = 4,
        min_candidate: int = 4,
    ) -> None:
        self.confidence_lv = confidence_lv
        self.min_effect = min_effect
        self.min_baseline = min_baseline
        self.min_candidate = min_candidate

    def _detect(self, base: np.ndarray, cand: np.ndarray) -> Detection:
        from scipy import stats  # where it runs: see `redline.detect`

        p_value = float(stats.mannwhitneyu(cand, base, alternative="two-sided").pvalue)
        score = -math.log10(max(p_value, 1e-300))
        effect = float(relative_effects(base, cand)[0])
        return _decide(
            self.name, score, p_value, p_value < self.confidence_lv, effect, self.min_effect
        )


def _linear_weighted_mean(values: np.ndarray) -> float:
    """Perfherder's ``linear_weights``: weight (n - i) / n, the first value weighing most."""
    n = len(values)
    weights = (n - np.arange(n)) / n
    return float(np.sum(values * weights) / np.sum(weights))


class WelchT(Detector):
    """Welch's t statistic with Perfherder's thresholds; the score is |t|.

    Source: Mozilla Treeherder/Perfherder ``perfalert`` ``detect_changes(data,
    min_back_window=12, max_back_window=24, fore_window=12, t_threshold=7)`` and ``calc_t``:
    t = (avg2 - avg1) / sqrt(s1^2/n1 + s2^2/n2) with linearly weighted averages (the values
    nearest the change weigh most; samples are taken in time order) and a change when
    ``|t| > 7``; Perfherder's alert threshold is a 2 % magnitude. ``min_baseline = 12`` is
    Perfherder's ``min_back_window`` (the newer Perfherder counts it in values). Perfherder
    also waits for ``fore_window = 12`` values after the change; Redline judges one execution,
    so ``min_candidate = 2`` (a variance needs two values). p from Welch-Satterthwaite df.
    """

    name = "welch_t"

    def __init__(
        self,
        t_threshold: float = 7.0,
        min_effect: float = 0.02,
        min_baseline: int = 12,
        min_candidate: int = 2,
    ) -> None:
        self.t_threshold = t_threshold
        self.min_effect = min_effect
        self.min_baseline = min_baseline
        self.min_candidate = min_candidate

    def _detect(self, base: np.ndarray, cand: np.ndarray) -> Detection:
        delta = _linear_weighted_mean(cand) - _linear_weighted_mean(base[::-1])
        var1, var2 = float(np.var(base, ddof=1)), float(np.var(cand, ddof=1))
        se2 = var1 / len(base) + var2 / len(cand)
        if delta == 0:
            t, p_value = 0.0, 1.0
        elif se2 == 0:
            t, p_value = math.inf, 0.0
        else:
            t = abs(delta) / math.sqrt(se2)
            df = se2**2 / (
                (var1 / len(base)) ** 2 / (len(base) - 1)
                + (var2 / len(cand)) ** 2 / (len(cand) - 1)
            )
            from scipy import stats  # where it runs: see `redline.detect`

            p_value = float(2 * stats.t.sf(t, df))
        effect = largest(relative_effects(base, cand))
        return _decide(self.name, t, p_value, t > self.t_threshold, effect, self.min_effect)
