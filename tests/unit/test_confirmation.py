"""Confirmation by history (`redline.detect.confirmation`): a flagged change is suspected until
later revisions measured it, held when they keep the new level, dropped when they return."""

from __future__ import annotations

import math

import numpy as np
import pytest
from redline.detect.config import ConfigError, DetectionConfig
from redline.detect.confirmation import (
    DROPPED,
    HELD,
    SUSPECTED,
    already_moved,
    hold,
    seen_before,
)

BASE = [100.0, 101.0, 99.0, 100.5, 99.5, 100.0]
UP = [130.0, 131.0, 129.0]


def test_a_change_is_suspected_until_enough_later_revisions_measured_it() -> None:
    found = hold(BASE, UP, [[130.0]], wait=2)
    assert found.state == SUSPECTED and "1 more revision" in found.reason
    assert math.isnan(found.kept)
    assert hold(BASE, UP, [[130.0], []], wait=2).state == SUSPECTED  # an empty one is no measure


def test_a_level_the_later_revisions_keep_holds() -> None:
    found = hold(BASE, UP, [[128.0, 129.0], [131.0], [100.0]], wait=2)  # only 2 count
    assert found.state == HELD and found.kept > 0.9
    assert "+30.0 %" in found.reason and "next 2 revision(s) at +29.0 %" in found.reason


def test_a_spike_that_returns_is_dropped_with_its_figures() -> None:
    found = hold(BASE, UP, [[101.0], [99.0]], wait=2)
    assert found.state == DROPPED and abs(found.kept) < 0.1
    assert "returned towards the old level" in found.reason and "+30.0 %" in found.reason


def test_half_the_step_is_the_line_and_direction_counts() -> None:
    assert hold(BASE, UP, [[116.0], [116.0]], wait=2).state == HELD  # 53 % of the step
    assert hold(BASE, UP, [[114.0], [114.0]], wait=2).state == DROPPED  # 47 %
    down = [70.0, 71.0]
    assert hold(BASE, down, [[72.0], [69.0]], wait=2).state == HELD  # a fall that stays
    assert hold(BASE, down, [[130.0], [130.0]], wait=2).state == DROPPED  # overshoots the other way


def test_counts_compare_means_not_medians() -> None:
    # timeouts per execution: mostly none before, a few in most executions after
    before, flagged = [0.0] * 9, [0.0, 3.0, 4.0]
    assert hold(before, flagged, [[0.0, 2.0, 3.0], [4.0, 0.0, 0.0]], count=True).state == HELD
    assert hold(before, flagged, [[0.0, 0.0, 0.0], [0.0] * 3], count=True).state == DROPPED


def test_waiting_for_no_revision_confirms_at_once_and_nothing_comparable_is_dropped() -> None:
    assert hold(BASE, UP, [], wait=0).state == HELD
    assert hold([math.nan], UP, [[1.0], [1.0]]).state == DROPPED
    assert hold(BASE, BASE, [[1.0], [1.0]]).state == DROPPED  # no step to confirm


def _visits(stretches: int, each: int, between: int) -> list[float]:
    """A past at the old level (100) that went to 130 ``stretches`` times, ``each`` values long."""
    return ([100.0] * between + [130.0] * each) * stretches + [100.0] * between


def test_a_level_the_series_kept_returning_to_is_not_new() -> None:
    # a bimodal series (SAP's "High deviation"): the later revisions keep the "new" level,
    # as they did several times before
    past = _visits(stretches=4, each=2, between=8)
    found = hold(BASE, UP, [[130.0], [129.0]], wait=2, past=past)
    assert found.state == DROPPED and found.kept > 0.9
    assert "the level is not new" in found.reason
    assert "17 % of the 48 values" in found.reason and "4 separate stretches" in found.reason
    assert "+30.0 %" in found.reason  # the figures stay
    assert hold(BASE, UP, [[130.0], [129.0]], wait=2).state == HELD  # without a past: held


def test_a_level_visited_once_or_rarely_is_new_again() -> None:
    # an improvement that was reverted: 130 once, for a long stretch, then 100, then 130 again
    reverted = [130.0] * 20 + [100.0] * 12
    assert hold(BASE, UP, [[130.0], [129.0]], wait=2, past=reverted).state == HELD
    # two short visits, or many visits that are a small share of the past
    assert hold(BASE, UP, [[130.0], [129.0]], past=_visits(2, 3, 8)).state == HELD
    assert hold(BASE, UP, [[130.0], [129.0]], past=_visits(3, 1, 30)).state == HELD
    assert hold(BASE, UP, [[130.0], [129.0]], past=_visits(3, 5, 30)).state == DROPPED  # 11 %


def test_the_old_levels_own_noise_does_not_make_a_level_old() -> None:
    # a noisy series with a small step: many past values beyond half-way, all within three
    # robust standard deviations of the baseline
    rng = np.random.default_rng(3)
    baseline = rng.normal(100.0, 8.0, 15)
    past = rng.normal(100.0, 8.0, 60)
    spread = 1.4826 * np.median(np.abs(baseline - np.median(baseline)))
    seen = seen_before(past, baseline, 112.0)
    beyond_half = np.mean(past > (np.median(baseline) + 112.0) / 2)
    assert beyond_half > 0.2 and 3 * spread > 6  # half-way alone would call it old
    assert seen.share < 0.05 and not seen.before
    assert hold(baseline, [112.0], [[112.0], [113.0]], past=past).state == HELD


def test_counts_and_an_empty_past_ignore_the_rule() -> None:
    before, flagged = [0.0] * 9, [0.0, 3.0, 4.0]
    bursty = [0.0, 0.0, 3.0] * 20  # timeouts came and went before: still a rate judged as such
    assert hold(before, flagged, [[2.0, 3.0], [4.0]], count=True, past=bursty).state == HELD
    assert seen_before([], BASE, 130.0).stretches == 0
    assert not seen_before([130.0] * 10, BASE, float(np.median(BASE))).before  # no step


def test_the_wait_is_part_of_a_components_configuration() -> None:
    assert DetectionConfig.parse(None).confirm_revisions == 2
    assert DetectionConfig.parse({"confirm_revisions": 0}).confirm_revisions == 0
    parsed = DetectionConfig.parse({"confirm_revisions": 5})
    assert DetectionConfig.parse(parsed.as_dict()) == parsed
    with pytest.raises(ConfigError, match="confirm_revisions: must be 0..10, not 11"):
        DetectionConfig.parse({"confirm_revisions": 11})
    with pytest.raises(ConfigError, match="confirm_revisions: must be a whole number"):
        DetectionConfig.parse({"confirm_revisions": "2"})


def test_pairs_confirm_a_change_most_of_them_show_and_name_what_did_not_run() -> None:
    from redline.detect.confirmation import pairs_hold

    shown = pairs_hold([(100.0, 131.0), (101.0, 128.0), (99.0, 100.0)], "increase", 0.3, 3)
    assert shown.state == HELD and "confirmed by 2 of 3 pairs" in shown.reason
    assert "+31.0 %" in shown.reason and "flagged +30.0 %" in shown.reason
    spike = pairs_hold([(100.0, 101.0), (100.0, 131.0)], "increase", 0.3, 2)
    assert spike.state == DROPPED and "showed in 1 of 2 pairs" in spike.reason
    fall = pairs_hold([(100.0, 80.0), (100.0, 82.0)], "decrease", -0.2, 2)
    assert fall.state == HELD
    assert pairs_hold([(100.0, 80.0)], "increase", 0.2, 1).state == DROPPED  # the other way
    # one complete pair alone decides nothing where two were wanted (a trial's demo confirmed
    # by "1 of 1 pairs; 2 pair(s) did not run": those had run, measured while the host was busy)
    partial = pairs_hold([(100.0, 130.0), (math.nan, 129.0)], "increase", 0.3, 2)
    assert partial.state == SUSPECTED, partial.reason
    assert partial.reason.startswith("re-runs could not decide: 2 pairs must show it")
    assert (
        "1 more pair(s) gave no value of it (a run measured while the host was busy"
        in partial.reason
    )
    alone = pairs_hold([(100.0, 130.0), (math.nan, 129.0), (100.0, math.nan)], "increase", 0.3, 3)
    assert alone.state == SUSPECTED and "2 more pair(s) gave no value" in alone.reason
    unshown = pairs_hold([(100.0, 101.0), (math.nan, 129.0)], "increase", 0.3, 2)
    assert unshown.state == DROPPED  # the missing pair could not make two of two
    held = pairs_hold([(100.0, 130.0), (100.0, 131.0), (math.nan, 99.0)], "increase", 0.3, 3)
    assert held.state == HELD and "confirmed by 2 of 2 pairs" in held.reason
    none = pairs_hold([], "increase", 0.3, 2)
    assert none.state == SUSPECTED and "none of the 2 confirmation pair(s) gave a value" in (
        none.reason
    )


def test_a_pair_shows_a_change_beyond_its_noise_not_beyond_half_the_flagged_step() -> None:
    """The winner's curse: a change flagged on one execution was flagged because its noise
    pushed it up. CPU +30 % flagged +52.5 % showed +14.5 % in its pair and was dropped against
    half the flagged step; against a pair's noise (3 % a value: a bar of 6.4 %) it holds, while
    one pair of an unchanged revision past it (+7 %, -2 %) does not confirm it."""
    from redline.detect.confirmation import pair_bar, pairs_hold

    cursed = [(100.0, 114.5), (100.0, 112.0)]
    assert pairs_hold(cursed, "increase", 0.525, 2).state == DROPPED  # half the step: 26 %
    held = pairs_hold(cursed, "increase", 0.525, 2, noise=0.03)
    assert held.state == HELD, held.reason
    assert "a pair shows it beyond +6.4 %, 1.5 sd of a pair's noise" in held.reason
    unchanged = pairs_hold([(100.0, 107.0), (100.0, 98.0)], "increase", 0.2, 2, noise=0.03)
    assert unchanged.state == DROPPED and "showed in 1 of 2 pairs" in unchanged.reason
    fall = pairs_hold([(100.0, 90.0), (100.0, 91.0)], "decrease", -0.3, 2, noise=0.03)
    assert fall.state == HELD and "beyond -6.4 %" in fall.reason
    # a series with next to no noise still needs a move worth reporting
    assert pair_bar(0.3, 0.0001) == 0.025
    assert pairs_hold([(100.0, 102.0)] * 2, "increase", 0.06, 2, noise=0.0001).state == DROPPED
    # no baseline values to measure the noise by: half the flagged step, as it says
    assert "half the flagged step" in pairs_hold(cursed, "increase", 0.525, 2).reason


def test_relative_noise_is_the_robust_spread_of_the_baseline_over_its_level() -> None:
    from redline.detect.confirmation import relative_noise

    rng = np.random.default_rng(5)
    noisy = rng.normal(200.0, 6.0, 2_000)
    assert relative_noise(noisy) == pytest.approx(0.03, rel=0.1)
    assert relative_noise([100.5] * 10) == pytest.approx(0.01)  # the floor: 1 % of the level
    assert relative_noise([14.0] * 15) == pytest.approx(0.1 / 14)  # a thread count: 0.1
    assert math.isnan(relative_noise([]))
    assert math.isnan(relative_noise([math.nan, math.inf]))
    assert math.isnan(relative_noise([0.0, 0.0, 0.0]))


def test_two_pairs_that_agree_decide_three_and_the_decision_is_what_all_would_give() -> None:
    from redline.detect.confirmation import pairs_decided, pairs_hold

    up, flat = (100.0, 131.0), (100.0, 101.0)
    assert pairs_decided([up, up], "increase", 0.3, pending=1)
    assert pairs_decided([flat, flat], "increase", 0.3, pending=1)
    assert not pairs_decided([up, flat], "increase", 0.3, pending=1)
    assert not pairs_decided([up], "increase", 0.3, pending=2)
    assert not pairs_decided([], "increase", 0.3, pending=3)
    assert pairs_decided([up, flat, up], "increase", 0.3, pending=0)
    # whatever the pending pairs show, or if they never run, the verdict stays the decided one
    rng = np.random.default_rng(3)
    outcomes = [(100.0, 131.0), (100.0, 101.0), (math.nan, 120.0), (100.0, 69.0)]
    for _ in range(2_000):
        wanted = int(rng.integers(1, 6))
        pairs = [outcomes[i] for i in rng.integers(0, len(outcomes), wanted)]
        direction, effect = ("increase", 0.3) if rng.random() < 0.5 else ("decrease", -0.3)
        for ran in range(wanted + 1):
            if pairs_decided(pairs[:ran], direction, effect, pending=wanted - ran):
                decided = pairs_hold(pairs[:ran], direction, effect, wanted).state
                assert pairs_hold(pairs, direction, effect, wanted).state == decided, pairs


def test_pairs_queued_again_are_decided_as_they_are_judged_wanting_only_the_first_ones() -> None:
    """Pairs queued again after a busy host (`redline.worker.quiet_pairs`) replace the first
    ones the host was busy in: the change is judged wanting as many pairs as were first queued,
    and a decision before the last of them has run is the one they all would give."""
    from redline.detect.confirmation import pairs_decided, pairs_hold

    up, busy = (100.0, 131.0), (math.nan, math.nan)
    # one busy of two first, then one that shows it: 2 of 2 wanted, decided, the 4th spared
    assert pairs_decided([up, busy, up], "increase", 0.3, pending=1, wanted=2)
    assert pairs_hold([up, busy, up], "increase", 0.3, 2).state == "held"
    # counted as every pair, four wanted, three must show it: not decided
    assert not pairs_decided([up, busy, up], "increase", 0.3, pending=1)
    rng = np.random.default_rng(4)
    outcomes = [(100.0, 131.0), (100.0, 101.0), busy, (100.0, 69.0)]
    for _ in range(2_000):
        first = int(rng.integers(1, 4))
        total = first + int(rng.integers(1, 4))
        pairs = [outcomes[i] for i in rng.integers(0, len(outcomes), total)]
        for ran in range(first, total + 1):
            if pairs_decided(pairs[:ran], "increase", 0.3, pending=total - ran, wanted=first):
                decided = pairs_hold(pairs[:ran], "increase", 0.3, first).state
                assert pairs_hold(pairs, "increase", 0.3, first).state == decided, pairs


def test_a_baseline_revision_rerun_at_the_new_level_already_moved() -> None:
    """CPU +10 % missed by its own revision's run, flagged at the next: the pair's run of the
    changed revision sits +10 % on its own baseline (2 % noise), beyond the bar; one at the old
    level, one moved the other way, or one within the noise, does not."""
    rng = np.random.default_rng(7)
    own = 100 * (1 + rng.normal(0, 0.02, 15))
    found = already_moved([110.0], own, "increase")
    assert found is not None
    assert found.moved == pytest.approx(0.10, abs=0.02)
    assert 0.025 <= found.bar < found.moved
    assert already_moved([100.5], own, "increase") is None
    assert already_moved([110.0], own, "decrease") is None
    assert already_moved([90.0], own, "decrease") is not None
    assert already_moved([100.0 + 100 * found.bar * 0.8], own, "increase") is None


def test_already_moved_needs_values_on_both_sides() -> None:
    assert already_moved([math.nan], [100.0] * 5, "increase") is None
    assert already_moved([110.0], [], "increase") is None
    assert already_moved([110.0], [0.0] * 5, "increase") is None
