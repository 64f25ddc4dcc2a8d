"""The execution-level default detector, the ``recent`` baseline policy, and the evaluation
walking a history as the service does (pure: synthetic arrays, milliseconds)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from redline.detect.baseline import recent_depth
from redline.detect.corpus import Corpus, SeriesLabel, first_executions
from redline.detect.evaluate import walk
from redline.detect.execution_shift import BuildShift, ExecutionShift, execution_values, values_for
from redline.detect.methods import WelchT
from redline.detect.result import CHANGE, NO_CHANGE, NOT_ENOUGH_DATA


def _executions(
    rng: np.random.Generator, level: float, count: int, between: float = 0.05, samples: int = 20
) -> list[np.ndarray]:
    """``count`` executions: each has its own level (5 % run-to-run noise) and noisy samples."""
    return [
        rng.normal(level * (1 + rng.normal(0, between)), level * 0.15, samples)
        for _ in range(count)
    ]


def test_execution_values_are_medians_so_one_spike_does_not_move_them() -> None:
    spiky = np.array([15.0] * 19 + [375.0])  # a descheduled sampler's one spike
    assert execution_values([spiky, np.array([1.0, 2.0, 30.0])]).tolist() == [15.0, 2.0]
    assert math.isnan(execution_values([np.array([])])[0])


def test_flags_a_30_percent_shift_of_executions_but_not_run_to_run_noise() -> None:
    rng = np.random.default_rng(3)
    baseline = execution_values(_executions(rng, 15.0, 15))
    raised = ExecutionShift().compare(baseline, execution_values(_executions(rng, 19.5, 5)))
    same = ExecutionShift().compare(baseline, execution_values(_executions(rng, 15.0, 5)))
    assert raised.verdict == CHANGE and raised.direction == "increase"
    assert raised.effect == pytest.approx(0.3, abs=0.08)
    assert same.verdict == NO_CHANGE and same.score < 1 <= raised.score


def test_pooled_samples_call_a_busier_run_significant_where_executions_do_not() -> None:
    """Why the default judges executions: one candidate execution 8 % busier than the rest is
    run-to-run noise; welch_t on pooled samples sees 20 tightly spread samples and flags it."""
    rng = np.random.default_rng(11)
    base_runs = [rng.normal(level, 0.3, 20) for level in (15.0, 15.6, 14.5, 15.2, 14.8, 15.4)]
    busier = [rng.normal(16.3, 0.3, 20)]
    assert WelchT().compare(np.concatenate(base_runs), busier[0]).flagged
    found = ExecutionShift().compare(execution_values(base_runs), execution_values(busier))
    assert found.verdict == NO_CHANGE, found


def test_score_is_one_exactly_where_both_margins_are_met() -> None:
    baseline = np.array([100.0, 100.2, 99.8, 100.1, 99.9, 100.0, 100.2, 99.8, 100.1])
    # spread = max(MAD, 1 % of 100) = 1: +3 gives z = 4.5, above the threshold
    detector = ExecutionShift(threshold=4.0, min_effect=0.05)
    tiny = detector.compare(baseline, np.array([103.0, 103, 103]))  # z large, effect 3 %
    assert tiny.verdict == NO_CHANGE and "below the floor 0.05" in tiny.reason
    assert tiny.score == pytest.approx(0.03 / 0.05)
    big = detector.compare(baseline, np.array([120.0, 121, 119]))
    assert big.verdict == CHANGE and big.score >= 1


def test_a_constant_count_that_moves_by_one_is_a_change() -> None:
    found = ExecutionShift().compare(np.full(15, 12.0), np.full(5, 13.0))  # one more thread
    assert found.verdict == CHANGE and found.effect == pytest.approx(1 / 12)
    # one execution of 15 threads against 15 of 14 (bench_verdicts' extra thread): with the
    # relative floor alone (0.14 of a thread) z was 6.9, under the threshold of 8
    one = ExecutionShift().compare(np.full(15, 14.0), np.array([15.0]))
    assert one.verdict == CHANGE and one.parts[0] == pytest.approx(1 / (0.1 * math.sqrt(16 / 15)))
    # a level that is no whole number, or a baseline that varies, keeps its relative floor
    assert ExecutionShift().compare(np.full(15, 14.5), np.array([15.5])).verdict == NO_CHANGE
    varied = np.array([14.0] * 14 + [15.0])
    assert ExecutionShift().compare(varied, np.array([15.0])).verdict == NO_CHANGE
    # and the effect floor still decides: one more of 30 is 3 %
    assert ExecutionShift().compare(np.full(15, 30.0), np.array([31.0])).verdict == NO_CHANGE


def test_a_step_between_two_constant_counts_is_found() -> None:
    detector = ExecutionShift()
    found = detector.step(np.full(6, 14.0), np.full(3, 15.0))
    assert found.verdict == CHANGE  # z = 1 / (0.1 * 0.71) = 14 against 8 * 1.25
    assert detector.step(np.full(6, 14.0), np.array([15.0, 14.0, 15.0])).verdict == NO_CHANGE


@pytest.mark.parametrize(
    ("baseline", "candidate", "reason"),
    [
        (None, [1.0], "missing baseline"),
        ([15.0, 15.2, 14.9], [20.0], "needs 6: 3 short; a change here is looked for again"),
        ([15.0] * 8, [15.0], "constant series"),
        ([15.0, 15.2, 14.9, 15.1, 15.3, math.inf], [20.0], "baseline contains NaN/inf"),
        ([15.0, 15.2, 14.9, 15.1, 15.3, 15.0], [math.nan], "candidate contains NaN/inf"),
    ],
)
def test_bad_input_is_not_enough_data_naming_what_is_missing(baseline, candidate, reason):
    found = ExecutionShift().compare(baseline, candidate)
    assert found.verdict == NOT_ENOUGH_DATA and reason in found.reason
    assert found.score == 0 and not found.flagged


def test_values_for_pools_samples_or_reduces_executions_by_the_detector_level() -> None:
    runs = [np.array([1.0, 2.0, 9.0]), np.array([4.0, 5.0]), np.array([7.0])]
    assert values_for(WelchT(), runs).tolist() == [1.0, 2.0, 9.0, 4.0, 5.0, 7.0]
    assert values_for(ExecutionShift(), runs).tolist() == [2.0, 4.5, 7.0]
    assert values_for(BuildShift(), runs).tolist() == [4.5]


def test_build_shift_judges_revisions_so_noise_shared_by_a_revision_is_not_a_change() -> None:
    """Executions of one revision share the host's state: this candidate's five agree with each
    other but sit 8 % above; revisions before it moved as much. Judged per execution the
    agreement looks significant; judged per revision it is one more ordinary revision."""
    rng = np.random.default_rng(8)
    levels = [15.0, 16.1, 14.6, 15.5, 14.3, 15.9, 14.8, 16.0, 15.2, 14.7]
    history = [[rng.normal(level, 0.1, 20) for _ in range(5)] for level in levels]
    candidate = [rng.normal(16.4, 0.1, 20) for _ in range(5)]
    for detector, verdict in (
        (ExecutionShift(threshold=3), CHANGE),
        (BuildShift(threshold=3), NO_CHANGE),
    ):
        baseline = np.concatenate(
            [values_for(detector, runs) for runs in history[-5:]]
            if detector.level == "execution"
            else [values_for(detector, runs) for runs in history]
        )
        assert detector.compare(baseline, values_for(detector, candidate)).verdict == verdict


@pytest.mark.parametrize(
    ("sizes", "need", "window", "flagged_at", "depth"),
    [
        ([3, 3, 3, 3, 3, 3], 15, 10, None, 5),  # pooled until 15 values
        ([3, 3, 3, 3, 3, 3], 15, 4, None, 4),  # at most `window` revisions
        ([3, 3, 3, 3, 3, 3], 15, 10, 1, 2),  # restarts at the flagged revision, which it keeps
        ([3, 3], 15, 10, None, 2),  # the history runs out
        ([60, 60], 12, 10, None, 1),  # one revision of samples is enough for a sample method
        ([], 12, 10, None, 0),
    ],
)
def test_recent_baseline_depth(sizes, need, window, flagged_at, depth) -> None:
    values = [np.full(size, 10.0) for size in sizes]
    assert recent_depth(values, need, window, lambda k: k == flagged_at) == depth


def _levels(*levels: float) -> list[np.ndarray]:
    """One execution per revision at these levels, newest first, with a little noise."""
    rng = np.random.default_rng(3)
    return [level * (1 + rng.normal(0, 0.01, 1)) for level in levels]


@pytest.mark.parametrize(
    ("levels", "depth", "why"),
    [
        ((14, 14, 14, 10, 10, 10, 10, 10), 3, "held by the 2 after it: the baseline starts there"),
        ((10, 14, 10, 10, 10, 10, 10, 10), 2, "1 after it: too soon to say, it starts there"),
        ((10, 10, 14, 10, 10, 10, 10, 10), 6, "the 2 after it returned: a spike, pooled past"),
    ],
)
def test_a_baseline_restarts_at_a_flag_only_while_it_may_be_a_new_level(levels, depth, why):
    """A trial's spike, flagged and dropped, left the next revisions judged against it alone
    ("not enough data") and then pooled a real change in unjudged (`redline.detect.baseline`)."""
    values = _levels(*levels)
    flagged_at = levels.index(14) if levels[0] != 14 else 2
    assert recent_depth(values, 6, 10, lambda k: k == flagged_at, wait=2) == depth, why


def _step_corpus(executions: int = 5) -> Corpus:
    """One series of 16 builds, 15 % CPU stepping to 19.5 % (+30 %) at build 8."""
    rng = np.random.default_rng(5)
    rows = []
    for build in range(16):
        level = 19.5 if build >= 8 else 15.0
        for number, values in enumerate(_executions(rng, level, executions, between=0.03)):
            rows += [("cpu", build, number, float(v)) for v in values]
    frame = pd.DataFrame(rows, columns=["series", "build", "execution", "value"])
    return Corpus("step", frame, {"cpu": SeriesLabel("regression", 8)})


def test_evaluation_restarts_the_baseline_after_a_flag_so_later_builds_are_not_flagged() -> None:
    judged = list(walk(ExecutionShift(), _step_corpus()))
    flagged = [unit.build for unit, found in judged if found.flagged]
    assert flagged == [8]
    after = {unit.build: unit for unit, _ in judged}
    assert len(after[9].baseline) == 5  # build 8's five executions only
    assert len(after[10].baseline) == 10  # builds 8 and 9: it stops at the flagged build
    assert len(after[12].baseline) == 15  # builds 9..11 hold the 15 values it needs
    assert len(after[7].baseline) == 15  # before the change: 3 builds x 5 executions


def test_without_a_restart_the_build_after_a_change_would_be_flagged_again() -> None:
    """The reason for the restart: judged against the old level, build 9 also 'changed'."""
    corpus = _step_corpus()
    judged = {unit.build: unit for unit, _ in walk(ExecutionShift(), corpus)}
    old_level = judged[8].baseline  # builds 5..7, before the change
    nine = execution_values(
        [
            g["value"].to_numpy()
            for _, g in corpus.measurements.query("build == 9").groupby("execution")
        ]
    )
    assert ExecutionShift().compare(old_level, nine).flagged


def test_first_executions_keeps_that_many_per_build() -> None:
    cut = first_executions(_step_corpus(), 3)
    assert set(cut.measurements.groupby("build")["execution"].nunique()) == {3}
    assert set(cut.measurements["execution"]) == {0, 1, 2}


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_an_execution_with_a_non_finite_sample_is_named_not_hidden_by_its_median(bad) -> None:
    runs = [np.array([15.0, 15.2, bad, 14.9, 15.1])]
    assert math.isnan(execution_values(runs)[0])
    found = ExecutionShift().compare(np.linspace(14, 16, 15), execution_values(runs))
    assert found.verdict == NOT_ENOUGH_DATA and "candidate contains NaN/inf" in found.reason


def test_the_fast_median_equals_numpys() -> None:
    from redline.detect.median_shift import median

    rng = np.random.default_rng(0)
    for size in (1, 2, 3, 10, 11, 60):
        values = rng.normal(0, 1, size)
        assert median(values) == pytest.approx(float(np.median(values)), abs=0)


def _blind(stretches: list[np.ndarray]) -> list[int]:
    """The revisions that had fewer than 6 values before them: not judged when measured."""
    sizes = np.cumsum([0, *map(len, stretches)])
    return [k for k in range(1, len(stretches)) if sizes[k] < 6]


def test_a_step_is_found_at_the_revision_it_came_with_and_needs_three_values_a_side() -> None:
    from redline.detect.execution_shift import strongest_step

    rng = np.random.default_rng(4)
    history = [rng.normal(level, 0.5, 1) for level in [10.0] * 3 + [20.0] * 3]
    k, found = strongest_step(ExecutionShift(), history, _blind(history))
    assert k == 3 and found.flagged and found.direction == "increase"
    assert 0.9 < found.effect < 1.1
    assert strongest_step(ExecutionShift(), history[:5], _blind(history[:5])) is None  # 2 after
    short = ExecutionShift().step(np.array([10.0, 10.1]), np.array([20.0, 20.1, 19.9, 20.2]))
    assert short.verdict == "not enough data" and "2 before" in short.reason


@pytest.mark.parametrize("per_revision", [1, 3])
def test_steps_on_unchanged_histories_are_rare_and_large_ones_are_found(per_revision) -> None:
    """The margin's figures (`STEP_MARGIN`): no false step on 3,000 unchanged histories of
    normal, heavy-tailed and skewed noise; a doubling found at its revision in most."""
    from redline.detect.execution_shift import strongest_step

    rng = np.random.default_rng(11)
    noises = [
        lambda n: rng.normal(100, 5, n),
        lambda n: 100 + 5 * rng.standard_t(3, n),
        lambda n: 100 * rng.lognormal(0, 0.15, n),
    ]
    false = 0
    for trial in range(3_000):
        noise = noises[trial % 3]
        history = [noise(per_revision) for _ in range(int(rng.integers(4, 11)))]
        false += strongest_step(ExecutionShift(), history, _blind(history)) is not None
    assert false == 0
    if per_revision == 1:  # with three a revision, the third is judged as it comes
        found = 0
        for _ in range(300):
            history = [rng.normal(100, 5, 1) for _ in range(3)]
            history += [rng.normal(200, 10, 1) for _ in range(3)]
            step = strongest_step(ExecutionShift(), history, _blind(history))
            found += step is not None and step[0] == 3
        assert found >= 0.8 * 300


def test_the_why_page_quotes_what_the_score_is_and_where_it_flags():
    """A trial read execution_shift's score of 0.902 as the shift itself: the paragraph the
    page quotes named the shift, not the score, and not that 1 or more flags."""
    from redline.server.services.why import _rule

    rule = _rule("execution_shift")
    assert "its score is the weaker of z / threshold and |effect| / min_effect" in rule
    assert "a score of 1 or more is a change" in rule
    assert "trial" not in rule and "page" not in rule  # a note to the code's reader, not the page's


def _one_execution_corpus(levels: list[float]) -> Corpus:
    """One series, one execution a build at ``levels`` (1 % between runs, 2 % in samples)."""
    rng = np.random.default_rng(11)
    rows = []
    for build, level in enumerate(levels):
        centre = level * (1 + (0.01, -0.01, 0.005, -0.005, 0.0)[build % 5])
        rows += [("cpu", build, 0, float(v)) for v in rng.normal(centre, level * 0.02, 40)]
    frame = pd.DataFrame(rows, columns=["series", "build", "execution", "value"])
    return Corpus("suspected", frame, {"cpu": SeriesLabel("regression", 9)})


def test_evaluation_judges_the_build_after_an_undecided_flag_as_the_worker_does() -> None:
    """`redline.detect.suspected`: a low run at build 8 (flagged), a real +30 % at build 9. The
    baseline restarted at build 8 was too short; the build is judged against the level before
    it (builds 0-7), as `tests/integration/test_suspected_level.py` sees the worker do."""
    judged = {
        unit.build: (unit, found)
        for unit, found in walk(ExecutionShift(), _one_execution_corpus([20.0] * 8 + [14.0, 26.0]))
    }
    assert judged[8][1].flagged and judged[8][1].direction == "decrease"
    unit, found = judged[9]
    assert found.flagged and found.direction == "increase", found.reason
    assert len(unit.baseline) == 8  # builds 0-7: the flagged build left out
    # a build at the suspected level shows that change: left undecided, not flagged again
    held = {
        unit.build: found
        for unit, found in walk(ExecutionShift(), _one_execution_corpus([20.0] * 8 + [26.0] * 2))
    }
    assert held[8].flagged and held[9].verdict == NOT_ENOUGH_DATA
    assert "shows that change" in held[9].reason


def test_a_short_new_level_is_judged_with_the_old_level_s_relative_noise() -> None:
    """`ExecutionShift.at_new_level`: 8 values at 20 (1 % noise), a new level of 3 at 26."""
    rng = np.random.default_rng(2)
    earlier = 20.0 * (1 + rng.normal(0, 0.01, 8))
    level = 26.0 * (1 + rng.normal(0, 0.01, 3))
    judge = ExecutionShift().confirmed()
    # at the new level: no change; 1 % noise in 26's units, not in 20's
    same = judge.at_new_level(level, earlier, np.array([26.0 * 1.01]))
    assert same.verdict == NO_CHANGE, same
    # +30 % on the new level: z = 7.8 / (0.26 x sqrt(4/3)) is far beyond 6
    raised = judge.at_new_level(level, earlier, np.array([33.8]))
    assert raised.verdict == CHANGE and raised.effect == pytest.approx(0.3, abs=0.03)
    # too few before it, or at it (with confirm_revisions 0 a flag holds at once: a new level
    # of its one value would make the next, unchanged revision a change), says so
    few = judge.at_new_level(level, earlier[:5], np.array([33.8]))
    assert few.verdict == NOT_ENOUGH_DATA and "5 before it (needs 6)" in few.reason
    alone = judge.at_new_level(level[:1], earlier, np.array([20.0]))
    assert alone.verdict == NOT_ENOUGH_DATA and "1 at it (needs 3)" in alone.reason
    # a count that does not vary: a tenth of one, so one more thread on 15 is a change
    threads = judge.at_new_level(np.full(3, 15.0), np.full(8, 14.0), np.array([16.0]))
    assert threads.verdict == CHANGE and threads.parts[0] == pytest.approx(1 / (0.1 * 2 / 3**0.5))


def test_after_a_fall_noise_that_does_not_shrink_with_the_level_raises_no_alarm() -> None:
    """A review: 100 +- 3 falling to 20 +- 3 (the noise a fixed overhead's, not a share of the
    level); the relative spread alone put it at 0.6 and flagged 28 % of unchanged revisions
    at threshold 6. Judged by the larger of the relative and the absolute spread, the rate is
    what the method gives on a long baseline (about 1 in 100 of these noisy draws or fewer)."""
    rng = np.random.default_rng(8)
    judge = ExecutionShift().confirmed()
    flagged = 0
    for _ in range(2000):
        earlier, level = rng.normal(100.0, 3.0, 15), rng.normal(20.0, 3.0, 3)
        found = judge.at_new_level(level, earlier, rng.normal(20.0, 3.0, 1))
        flagged += found.flagged
    assert flagged <= 20, flagged  # 0 here; the relative spread alone flagged 500-600


def test_evaluation_judges_a_held_change_s_short_new_level_as_the_worker_does() -> None:
    """A +30 % at build 8 that holds, another at build 11: build 11's baseline (builds 8-10,
    3 values) was too short to judge by; judged at the new level with the old one's noise."""
    judged = {
        unit.build: found
        for unit, found in walk(
            ExecutionShift(), _one_execution_corpus([20.0] * 8 + [26.0] * 3 + [34.0] * 2)
        )
    }
    assert judged[8].flagged and not judged[9].flagged and not judged[10].flagged
    assert judged[11].flagged and judged[11].direction == "increase", judged[11].reason
    assert "judged against the new level since the change at 8 (3 value(s))" in judged[11].reason


def test_a_spike_and_the_flag_the_other_way_after_it_leave_no_baseline_at_the_spike() -> None:
    """A review: a low run at build 8 (flagged), 26 at build 9 (flagged the other way against
    the level before 8), then 21 throughout. Build 9's restart was tested against build 8's
    one value ("held"), and the level before build 9 was read as build 8 alone; both now read
    past a flag at most ``wait`` builds before (`redline.detect.baseline._restarts_at`)."""
    judged = {
        unit.build: (unit, found)
        for unit, found in walk(
            ExecutionShift(), _one_execution_corpus([20.0] * 8 + [14.0, 26.0] + [21.0] * 8)
        )
    }
    assert [b for b, (_, found) in judged.items() if found.flagged] == [8, 9]
    for build in range(10, 18):
        assert judged[build][1].verdict == NO_CHANGE, (build, judged[build][1].reason)
    # from build 12 both flags are decided as spikes: the baseline pools past them (it
    # restarted at build 9 before, as a level 26 "held" against build 8's 14)
    for build in range(12, 18):
        unit, found = judged[build]
        assert len(unit.baseline) == 10 and "new level" not in found.reason, build
