"""A change of the median past a relative threshold, for series with one value per recording.

A driver's quantiles (a round trip's p50, FixedRate's achieved rate) are one value per segment
and recording: comparing a few recordings with a few others, no test has the values to judge by.
This detector judges them as pytest-benchmark's ``--benchmark-compare-fail=median:10%`` does, a
change when the median moved by ``min_effect`` of the baseline's median or more (the counter's
absolute floor applies on top, in `redline.detect.verdict`), and asks two things more, because a
new user's unchanged code moved a round trip's p90 by -34 % from one run to the next: at least
``min_baseline`` and ``min_candidate`` values (3: one value a side cannot tell a change from
noise), and no overlap, every candidate value beyond the baseline's range in the direction of
the change. ``min_effect = 0.10``: ours, pytest-benchmark's example threshold. Where there are
enough executions, the service judges the same series with its configured methods.
"""

from __future__ import annotations

import math

import numpy as np
from redline.detect.methods import Detector
from redline.detect.result import CHANGE, NO_CHANGE, Detection, check_samples, direction_of
from redline.detect.result import not_enough as abstain


class RelativeChange(Detector):
    """``|median(c) - median(b)| / |median(b)| >= min_effect``; the score is the relative change
    in units of ``min_effect`` (so score >= 1 exactly when it is a change)."""

    name = "relative_change"
    level = "execution"
    baseline_values = 1

    def __init__(
        self, min_effect: float = 0.10, min_baseline: int = 3, min_candidate: int = 3
    ) -> None:
        self.min_effect = min_effect
        self.min_baseline = min_baseline
        self.min_candidate = min_candidate

    def detect(self, candidate: object) -> Detection:
        checked = check_samples(
            getattr(self, "baseline_", None),
            candidate,
            min_baseline=self.min_baseline,
            min_candidate=self.min_candidate,
        )
        if isinstance(checked, str):
            if checked.startswith("constant series"):  # the same value throughout: no change
                return Detection(method=self.name, verdict=NO_CHANGE, reason=checked)
            if checked.startswith("too few samples"):
                checked += " (one value per execution: run each side with --executions 3 or more)"
            return abstain(self.name, checked)
        return self._detect(*checked)

    def _detect(self, base: np.ndarray, cand: np.ndarray) -> Detection:
        before, after = float(np.median(base)), float(np.median(cand))
        if before == 0:
            effect = 0.0 if after == 0 else math.copysign(math.inf, after)
        else:
            effect = (after - before) / abs(before)
        score = abs(effect) / self.min_effect
        apart = cand.min() > base.max() if effect > 0 else cand.max() < base.min()
        reason = f"median {before:.4g} -> {after:.4g}"
        if score >= 1 and not apart:
            reason += " (within the baseline's range: not told from noise)"
            score = min(score, 0.99)
        return Detection(
            method=self.name,
            verdict=CHANGE if score >= 1 else NO_CHANGE,
            score=score,
            effect=effect,
            direction=direction_of(effect),
            reason=reason,
        )
