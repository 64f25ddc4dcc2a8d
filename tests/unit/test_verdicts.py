"""Judging one series, the detection configuration and the worker's sample cache, without a
database: arrays in, verdicts out."""

from __future__ import annotations

import re

import numpy as np
import pytest
from redline.detect.config import ConfigError, DetectionConfig
from redline.detect.methods import KolmogorovSmirnov
from redline.detect.verdict import TOO_FEW, judge_series
from redline.worker.samples import SampleCache


class _Broken(KolmogorovSmirnov):
    def _detect(self, base: np.ndarray, cand: np.ndarray):  # noqa: ANN202
        raise RuntimeError("boom")


def test_a_failing_method_is_a_verdict_naming_the_error_not_an_exception():
    verdict = judge_series(_Broken(), "cpu", np.arange(10.0), np.arange(10.0) + 5)
    assert verdict.verdict == "not enough data" and "RuntimeError: boom" in verdict.reason


def test_the_absolute_floor_keeps_a_tiny_significant_change_quiet():
    rng = np.random.default_rng(1)
    base, cand = rng.normal(4.0, 0.05, 200), rng.normal(4.6, 0.05, 200)
    assert judge_series(KolmogorovSmirnov(), "x", base, cand).flagged
    quiet = judge_series(KolmogorovSmirnov(), "small_cpu_percent", base, cand)
    assert quiet.verdict == "no change" and "absolute floor" in quiet.reason


@pytest.mark.parametrize(
    ("level", "factor"),
    [
        (8.5, 1.10),  # CPU +10 % at the example's 8 legs (8-9 references an operation): +0.85
        (0.3, 3.0),  # a light component's CPU tripled (0.3 references, about 100 µs): +0.6
    ],
)
def test_the_cpu_in_references_is_not_floored_as_if_in_microseconds(level, factor):
    """``cpu_refs_per_op`` counts the host's reference work (280-430 µs here), not µs: under
    the 1.0 that a microsecond count needs, each of these was called no change by the default
    method (a component under one reference an operation could not be flagged on CPU)."""
    from redline.detect.execution_shift import ExecutionShift

    rng = np.random.default_rng(3)
    base, cand = rng.normal(level, level / 100, 12), np.array([level * factor])
    judge = ExecutionShift().confirmed()
    assert judge_series(judge, "cpu_refs_per_op", base, cand).flagged
    # the same figures in microseconds are within a microsecond's floor: no change
    micro = judge_series(judge, "cpu_us_per_op", base, cand)
    assert micro.verdict == "no change" and "absolute floor 1 of cpu_us_per_op" in micro.reason


@pytest.mark.parametrize(
    ("config", "field"),
    [
        ({"methods": ["e_divisive"]}, "methods"),
        ({"baseline": "last"}, "baseline"),
        ({"baseline": "pinned"}, "pinned"),
        ({"thresholds": {"ks": {"beta": 1}}}, "thresholds.ks"),
        ({"window": 0}, "window"),
        # of the wrong kind or range: stored, they failed every verdict of their method (a trial)
        ({"thresholds": {"ks": {"alpha": "high"}}}, "thresholds.ks.alpha: must be a number"),
        ({"thresholds": {"ks": {"alpha": -1}}}, "thresholds.ks.alpha: must be between 0 and 1"),
        ({"thresholds": {"ks": {"min_baseline": 2.5}}}, "ks.min_baseline: must be a whole"),
        ({"thresholds": {"execution_shift": {"threshold": True}}}, "threshold: must be a number"),
        ({"thresholds": {"execution_shift": {"min_effect": -0.1}}}, "min_effect: must be 0 or"),
    ],
)
def test_bad_configuration_names_the_field(config, field):
    with pytest.raises(ConfigError, match=re.escape(field)):
        DetectionConfig.parse(config)


def test_thresholds_of_the_right_kind_are_taken():
    config = DetectionConfig.parse(
        {
            "thresholds": {
                "ks": {"alpha": 0.05, "min_baseline": 3},
                "execution_shift": {"threshold": 6},
            }
        }
    )
    assert config.detectors()[1].alpha == 0.05


def test_median_shift_ignores_a_few_huge_outliers_that_move_the_mean():
    from redline.detect.median_shift import MedianShift
    from redline.detect.methods import WelchT

    rng = np.random.default_rng(2)
    base = rng.normal(15.0, 0.5, 60)
    cand = rng.normal(15.0, 0.5, 60)
    cand[:2] = 375.0  # a descheduled sampler's spike, as seen in corpus 2
    assert MedianShift().compare(base, cand).verdict == "no change"
    assert WelchT().compare(np.r_[base, base], cand).effect > 0.5  # the mean moved 80 %
    shifted = MedianShift().compare(base, base * 1.2)
    assert shifted.flagged and shifted.effect == pytest.approx(0.2, abs=0.01)
    assert MedianShift().compare(base, cand[:3]).verdict == "not enough data"


def test_sample_cache_keeps_only_the_newest_revisions_it_is_sized_for():
    cache = SampleCache(3)
    for revision_id in range(1, 7):
        cache.put(revision_id, {1: [np.full(2, float(revision_id))]})
    assert list(cache.entries) == [4, 5, 6]
    assert cache.get(None, 5)[1][0].tolist() == [5.0, 5.0]  # a hit reads nothing
    cache.put(5, {1: [np.zeros(1)]})  # replacing keeps the bound
    assert len(cache.entries) == 3 and cache.get(None, 5)[1][0].tolist() == [0.0]


def test_ks_in_the_service_says_too_few_to_decide_where_it_cannot_reach_significance() -> None:
    """A third trial's server said "no change" of a round trip +100 % with D = 1 (three values a
    side: KS's smallest p is 0.1), where `redline compare` said "too few values to decide"."""
    base, cand = np.array([100.0, 102.0, 101.0]), np.array([201.0, 203.0, 199.0])
    found = judge_series(KolmogorovSmirnov(), "rtt_p50_us", base, cand)
    assert found.verdict == "not enough data", found
    assert found.reason.startswith(TOO_FEW) and "smallest p here: 0.1" in found.reason
    many = judge_series(KolmogorovSmirnov(), "rtt_p50_us", np.tile(base, 5), np.tile(cand, 5))
    assert many.flagged  # with 15 a side it decides
    close = judge_series(KolmogorovSmirnov(), "rtt_p50_us", base, base + 1.5)
    assert close.verdict == "no change"  # overlapping sides: KS's "no change" stands
