"""Detectors on synthetic data (milliseconds), bad input, E-divisive, and evaluation metrics."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from redline.commands.evaluate import as_json
from redline.detect.aggregate import aggregate, compare_test
from redline.detect.association_rules import FooRules
from redline.detect.changepoint import EDivisive
from redline.detect.corpus import Corpus, SeriesLabel, load_corpus, write_corpus
from redline.detect.counter_clusters import ShangRegression
from redline.detect.evaluate import run_detector, walk
from redline.detect.methods import KolmogorovSmirnov, MannWhitney, WelchT
from redline.detect.result import CHANGE, NO_CHANGE, NOT_ENOUGH_DATA
from redline.detect.scores import precision_recall_f1, roc_auc, summarize

SERIES_METHODS = [KolmogorovSmirnov, MannWhitney, WelchT]
COUNTER_METHODS = [FooRules, ShangRegression]


def _counters(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    """Three counters of one component: cpu and latency follow the load, memory does not."""
    load = rng.uniform(1.0, 2.0, n)
    cpu = 10 * load + rng.normal(0, 0.2, n)
    latency = 5 * load + rng.normal(0, 0.1, n)
    memory = 50 + rng.normal(0, 0.5, n)
    return np.column_stack([cpu * scale, memory * scale, latency])


@pytest.mark.parametrize("method", SERIES_METHODS)
def test_series_method_flags_a_30_percent_shift_and_not_identical_distributions(method) -> None:
    rng = np.random.default_rng(7)
    baseline = rng.normal(100, 3, 40)
    shifted = method().compare(baseline, rng.normal(130, 3, 20))
    same = method().compare(baseline, rng.normal(100, 3, 20))
    assert shifted.verdict == CHANGE and shifted.direction == "increase"
    assert shifted.effect == pytest.approx(0.30, abs=0.03)
    assert same.verdict == NO_CHANGE
    assert shifted.score > same.score


@pytest.mark.parametrize("method", COUNTER_METHODS)
def test_counter_method_flags_a_30_percent_shift_and_not_identical_distributions(method) -> None:
    rng = np.random.default_rng(11)
    baseline = _counters(rng, 60)
    shifted = method().compare(baseline, _counters(rng, 20, scale=1.3))
    same = method().compare(baseline, _counters(rng, 20))
    assert shifted.verdict == CHANGE, shifted
    assert same.verdict == NO_CHANGE, same
    assert shifted.score > same.score


BAD_INPUTS = {
    "missing baseline": (None, [1.0, 2.0, 3.0, 4.0, 5.0]),
    "too few samples": (list(np.linspace(1, 2, 20)), [1.5]),
    "constant series": ([3.0] * 20, [3.0] * 6),
    "NaN/inf": (list(np.linspace(1, 2, 20)), [1.0, math.nan, 2.0, 1.5, 1.2]),
}


@pytest.mark.parametrize("method", SERIES_METHODS + COUNTER_METHODS)
@pytest.mark.parametrize("reason", sorted(BAD_INPUTS))
def test_bad_input_gives_not_enough_data_with_the_reason(method, reason: str) -> None:
    baseline, candidate = BAD_INPUTS[reason]
    if reason == "too few samples" and method in COUNTER_METHODS:
        baseline = baseline[:3]  # these methods judge one candidate sample; their floor is 5
    found = method().compare(baseline, candidate)
    assert found.verdict == NOT_ENOUGH_DATA
    assert reason in found.reason
    assert found.score == 0.0 and not found.flagged


def test_effect_floor_keeps_a_significant_but_tiny_change_quiet() -> None:
    rng = np.random.default_rng(3)
    baseline, candidate = rng.normal(100, 0.1, 200), rng.normal(101, 0.1, 200)
    found = KolmogorovSmirnov().compare(baseline, candidate)
    assert found.p_value < 1e-10 and found.verdict == NO_CHANGE
    assert "floor" in found.reason


def test_per_counter_floor_ignores_a_counter_with_a_high_floor() -> None:
    rng = np.random.default_rng(11)
    baseline, shifted = _counters(rng, 60), _counters(rng, 20, scale=1.3)
    assert (
        ShangRegression(min_effect=[1.0, 1.0, 0.1]).compare(baseline, shifted).verdict == NO_CHANGE
    )


def test_aggregation_min_max_mean_and_missing_series() -> None:
    rng = np.random.default_rng(5)
    base = {"a": rng.normal(10, 1, 30), "b": rng.normal(20, 1, 30)}
    cand = {"a": rng.normal(13, 1, 10), "b": rng.normal(20, 1, 10), "c": rng.normal(5, 1, 10)}
    parts = [KolmogorovSmirnov().compare(base[k], cand[k]).score for k in ("a", "b")]
    for how, expected in (("min", min(parts)), ("max", max(parts)), ("mean", np.mean(parts))):
        test = compare_test(KolmogorovSmirnov(), base, cand, how=how)
        assert test.score == pytest.approx(expected)
        assert test.verdict == CHANGE and "1 of 3 series had not enough data" in test.reason
    assert aggregate([]).verdict == NOT_ENOUGH_DATA


def test_e_divisive_finds_a_planted_change_point() -> None:
    rng = np.random.default_rng(2)
    series = np.concatenate([rng.normal(100, 3, 70), rng.normal(125, 3, 50)])
    found = EDivisive(permutations=99).detect(series)
    assert found.verdict == CHANGE
    assert [p.index for p in found.change_points if p.reported] == [70]
    assert found.change_points[0].p_value <= 0.05


def test_e_divisive_finds_nothing_in_noise_and_reports_bad_input() -> None:
    rng = np.random.default_rng(4)
    assert EDivisive(permutations=99).detect(rng.normal(100, 3, 120)).verdict == NO_CHANGE
    short = EDivisive().detect([1.0, 2.0, 3.0])
    assert short.verdict == NOT_ENOUGH_DATA and "too few samples" in short.reason
    assert "NaN/inf" in EDivisive().detect([1.0] * 20 + [math.inf]).reason


def test_roc_auc_precision_recall_f1_equal_hand_computed_values() -> None:
    positive = [True, False, True, False, False]
    scores = [0.9, 0.8, 0.3, 0.3, 0.1]
    # positive pairs: (0.9 beats all 3 negatives) + (0.3 beats 0.1, ties 0.3, loses to 0.8)
    assert roc_auc(positive, scores) == pytest.approx((3 + 1.5) / 6)
    precision, recall, f1, tp, fp, fn = precision_recall_f1(
        positive, [True, True, False, False, False]
    )
    assert (tp, fp, fn) == (1, 1, 1)
    assert (precision, recall, f1) == (0.5, 0.5, 0.5)
    assert math.isnan(roc_auc([False, False], [0.1, 0.2]))


def _tiny_corpus() -> Corpus:
    rows = [
        ("s1", b, v)
        for b, values in ((1, [10.0, 10.2, 9.9]), (2, [10.1, 9.8, 10.0]), (3, [13.0, 13.2, 12.9]))
        for v in values
    ]
    rows += [
        ("s2", b, v) for b, values in ((1, [5.0, 5.1, 4.9]), (2, [5.05, 4.95, 5.0])) for v in values
    ]
    frame = pd.DataFrame(rows, columns=["series", "build", "value"])
    labels = {"s1": SeriesLabel("regression", 3), "s2": SeriesLabel("Stable")}
    return Corpus("tiny", frame, labels)


def test_units_and_metrics_on_a_tiny_hand_made_corpus() -> None:
    units = [unit for unit, _ in walk(WelchT(min_baseline=3), _tiny_corpus())]
    # the baseline pools every earlier build (welch_t wants 12 values; there are at most 6)
    assert [(u.series, u.build, u.positive, len(u.baseline)) for u in units] == [
        ("s1", 2, False, 3),
        ("s1", 3, True, 6),
        ("s2", 2, False, 3),
    ]
    scores = summarize(run_detector(WelchT(min_baseline=3), _tiny_corpus()))
    # only s1 build 3 moves (by 30 %): flagged, the two stable builds are not
    assert (scores.tp, scores.fp, scores.fn) == (1, 0, 0)
    assert (scores.roc_auc, scores.precision, scores.recall, scores.f1) == (1.0, 1.0, 1.0, 1.0)


def test_corpus_round_trips_through_the_documented_format(tmp_path: Path) -> None:
    write_corpus(_tiny_corpus(), tmp_path)
    loaded = load_corpus(str(tmp_path))
    assert loaded.labels == _tiny_corpus().labels
    # every sample of a corpus without executions is taken for its own execution
    expected = _tiny_corpus().measurements.assign(execution=[0, 1, 2] * 5)
    assert loaded.measurements.equals(expected)


def test_json_output_has_exactly_the_documented_keys() -> None:
    scores = summarize(run_detector(WelchT(min_baseline=3), _tiny_corpus()))
    out = json.loads(as_json({"welch_t": scores}))
    assert set(out) == {"default", "confirm", "methods"}
    assert set(out["methods"]["welch_t"]) == {
        "roc_auc",
        "precision",
        "recall",
        "f1",
        "tp",
        "fp",
        "fn",
        "units",
        "decided",
        "false_alarms_per_100",
        "recall_large",
        "large",
    }


def test_e_divisive_statistic_equals_the_energy_formula_computed_directly() -> None:
    from redline.detect.changepoint import split_statistics

    x = np.random.default_rng(9).normal(0, 1, 12)
    q = split_statistics(x, min_size=3, alpha=1.0)
    for tau in range(3, 10):
        left, right = x[:tau], x[tau:]
        between = np.abs(left[:, None] - right[None, :]).mean()
        within_l = np.abs(left[:, None] - left[None, :]).sum() / (tau * (tau - 1))
        within_r = np.abs(right[:, None] - right[None, :]).sum() / ((12 - tau) * (11 - tau))
        expected = tau * (12 - tau) / 12 * (2 * between - within_l - within_r)
        assert q[tau] == pytest.approx(expected)
