"""The KS detector as a pure function on synthetic samples."""

from __future__ import annotations

import math

import numpy as np
import pytest
from redline.detect.ks import DEFAULT_ALPHA, DEFAULT_MIN_EFFECT, ks, relative_effect

rng = np.random.default_rng(42)


def test_same_distribution_is_not_flagged():
    result = ks(rng.normal(100, 10, 500), rng.normal(100, 10, 500))
    assert not result.flagged
    assert result.p_value > DEFAULT_ALPHA and abs(result.effect) < DEFAULT_MIN_EFFECT


def test_tripled_mean_is_flagged_with_its_effect():
    base = rng.normal(20, 2, 200)
    result = ks(base, 3 * rng.normal(20, 2, 200))
    assert result.flagged
    assert result.statistic == pytest.approx(1.0)
    assert result.p_value < 1e-10
    assert result.effect == pytest.approx(2.0, abs=0.1)


def test_improvement_is_flagged_with_a_negative_effect():
    result = ks(rng.normal(100, 5, 300), rng.normal(50, 5, 300))
    assert result.flagged and result.effect == pytest.approx(-0.5, abs=0.05)


def test_significant_but_tiny_shift_stays_below_the_effect_floor():
    base = rng.normal(100, 1, 5000)
    result = ks(base, rng.normal(102, 1, 5000))  # 2 %: clear to KS, too small to report
    assert result.p_value < DEFAULT_ALPHA and not result.flagged
    assert ks(base, rng.normal(102, 1, 5000), min_effect=0.01).flagged


def test_large_shift_on_too_few_samples_is_not_flagged():
    result = ks(np.array([10.0, 11.0]), np.array([20.0, 21.0]))
    assert result.effect > 0.5 and result.p_value >= DEFAULT_ALPHA and not result.flagged


def test_distribution_change_with_the_same_mean_moves_d_but_not_the_effect():
    base = rng.normal(100, 1, 2000)
    wide = rng.normal(100, 30, 2000)
    result = ks(base, wide)
    assert result.statistic > 0.3 and result.p_value < DEFAULT_ALPHA
    assert abs(result.effect) < DEFAULT_MIN_EFFECT and not result.flagged


def test_relative_effect_of_a_zero_baseline():
    assert relative_effect(np.zeros(3), np.zeros(3)) == 0.0
    assert relative_effect(np.zeros(3), np.ones(3)) == math.inf
    assert relative_effect(np.array([-4.0]), np.array([-2.0])) == pytest.approx(0.5)


def test_empty_sample_is_refused_naming_which():
    with pytest.raises(ValueError, match="baseline has 0"):
        ks(np.array([]), np.ones(3))


def test_absolute_floor_keeps_a_clear_but_tiny_change_quiet():
    rng = np.random.default_rng(7)
    base = rng.normal(4.0, 0.05, 100)
    cand = base * 1.2  # +0.8 points: 20 % relative
    assert ks(base, cand).flagged
    assert not ks(base, cand, min_change=1.0).flagged
    assert ks(base, cand * 2, min_change=1.0).flagged


def test_floors_by_counter_name():
    from redline.detect.floors import MIB, absolute_floor

    assert absolute_floor("cpu_percent") == 1.0
    assert absolute_floor("rss_bytes") == MIB
    assert absolute_floor("threads") == 1.0
    assert absolute_floor("ctx_voluntary_per_s") == 10.0
    assert absolute_floor("latency_ms") == 0.0


@pytest.mark.parametrize(
    ("n_base", "n_cand", "shift", "decimals"),
    [
        (30, 20, 0.3, None),
        (12, 3, 1.0, None),
        (60, 60, 0.0, None),
        (200, 20, 0.1, None),
        (15, 5, 0.5, 0),  # ties: values rounded to whole numbers
    ],
)
def test_ks_gives_exactly_what_scipys_public_ks_2samp_gives(n_base, n_cand, shift, decimals):
    from scipy import stats

    rng = np.random.default_rng(n_base + n_cand)
    base, cand = rng.normal(10, 1, n_base), rng.normal(10 + shift, 1, n_cand)
    if decimals is not None:
        base, cand = np.round(base, decimals), np.round(cand, decimals)
    expected = stats.ks_2samp(base, cand)
    found = ks(base, cand)
    assert (found.statistic, found.p_value) == (expected.statistic, expected.pvalue)
