"""A flag its pairs confirmed is a decided level (`redline.detect.baseline.Flag.CONFIRMED`), and a
short one before a later flag is judged with the spread of the nearest long level before it
(`redline.detect.suspected.LevelBefore`); `tests/integration/test_suspected_level.py` has a
trial's whole history through the worker."""

from __future__ import annotations

import numpy as np
import pytest
from redline.detect.baseline import Flag, take_recent
from redline.detect.execution_shift import ExecutionShift
from redline.detect.result import CHANGE, NO_CHANGE, NOT_ENOUGH_DATA, Detection
from redline.detect.suspected import RESTARTED, LevelBefore, after_flag, at_new_level
from redline.detect.verdict import judge_series


def _revisions(*flags: Flag) -> list[tuple[int, np.ndarray, Flag]]:
    """Revisions 0.. newest first, three values each, flagged as given."""
    return [(k, np.full(3, 10.0 + k), flag) for k, flag in enumerate(flags)]


NONE, UNDECIDED, CONFIRMED = Flag.NONE, Flag.UNDECIDED, Flag.CONFIRMED


@pytest.mark.parametrize(
    ("flags", "taken", "why"),
    [
        ((UNDECIDED, NONE, NONE, NONE, NONE, NONE), [1, 2, 3, 4, 5], "undecided: read past"),
        ((True, NONE, NONE, NONE, NONE, NONE), [1, 2, 3, 4, 5], "a bool reads as a Flag"),
        ((CONFIRMED, NONE, NONE, NONE, NONE, NONE), [0], "confirmed: the level starts there"),
        ((NONE, CONFIRMED, NONE, NONE, NONE, NONE), [0, 1], "one revision further back"),
        ((NONE, NONE, UNDECIDED, NONE, NONE, NONE), [0, 1, 2], "wait revisions back: a level"),
    ],
)
def test_the_level_before_a_flag_is_not_read_past_a_flag_its_pairs_confirmed(
    flags, taken, why
) -> None:
    found = take_recent(_revisions(*flags), need=15, wait=2, past_undecided=True)
    assert found == taken, why


def _revision(rng: np.random.Generator, level: float, between: float = 0.03) -> np.ndarray:
    """One revision's three execution values: ``between`` of noise shared by the revision (the
    host's state while it ran), 1 % apart within it."""
    return level * (1 + rng.normal(0, between)) * (1 + rng.normal(0, 0.01, 3))


def test_a_short_confirmed_level_is_judged_with_the_spread_of_a_long_one_before_it() -> None:
    rng = np.random.default_rng(4)
    noise = np.concatenate([_revision(rng, 40.0) for _ in range(5)])
    short = _revision(rng, 20.0)
    judge = ExecutionShift().confirmed()
    before = LevelBefore(short, noise, "r9")
    raised = before.judge(judge, "cpu_percent", short * 1.3)
    assert raised.verdict == CHANGE and "since the change at r9 (3 value(s))" in raised.reason
    assert before.judge(judge, "cpu_percent", short * 1.01).verdict == NO_CHANGE
    # alone, its three values are too few to judge by
    alone = LevelBefore(short).judge(judge, "cpu_percent", short * 1.3)
    assert alone.verdict == NOT_ENOUGH_DATA, alone
    assert before.spread_from is noise and LevelBefore(short).spread_from is short


def test_an_unchanged_revision_after_a_short_confirmed_level_raises_few_alarms() -> None:
    """A review: judged against one revision's level, noise the revision's executions share
    (3 % here, three times the spread within one) is read from the long level's values. Of
    2,000 unchanged revisions judged so, the alarms (threshold 6, a pairs-confirmed
    component's) stay rare."""
    rng = np.random.default_rng(9)
    judge = ExecutionShift().confirmed()
    flagged = 0
    for _ in range(2000):
        noise = np.concatenate([_revision(rng, 40.0) for _ in range(5)])
        before = LevelBefore(_revision(rng, 20.0), noise, "r9")
        flagged += before.judge(judge, "cpu_percent", _revision(rng, 20.0)).flagged
    assert flagged <= 4, flagged  # 0 here, at 1 %, 3 % and 6 % shared, thresholds 6 and 8


def _after_confirmed(
    rng: np.random.Generator, step: float, between: float, back: bool
) -> tuple[Detection, Detection]:
    """A revision judged right after a change of ``step`` its pairs confirmed (five revisions
    before it, one at it), at the level before the change (``back``) or at the new one: its
    verdict against the new level alone (`at_new_level`) and with a return told (`after_flag`)."""
    judge = ExecutionShift().confirmed()
    old = np.concatenate([_revision(rng, 20.0, between) for _ in range(5)])
    new = _revision(rng, 20.0 * (1 + step), between)
    cand = _revision(rng, 20.0 if back else 20.0 * (1 + step), between)
    found = judge_series(judge, "cpu_percent", new, cand)
    level = at_new_level(found, judge, "cpu_percent", new, old, cand, "r9", 1)
    told, against = after_flag(
        found, judge, "cpu_percent", new, LevelBefore(old), cand, "r9", held=False, confirmed=True
    )
    assert against == RESTARTED
    return level, told


def test_a_revert_of_a_confirmed_change_is_flagged_as_a_return() -> None:
    """A fourth trial: a regression doubling the work on a noisy component, confirmed by its
    pairs, and its revert "no change -49.5 %" against the regression's three values: pooled
    with them, the reland after it passed. Back at the level before the change, a revision is
    flagged as a return (the revisions after it decide); of 500 simulated reverts at 15 % of
    noise between revisions, 60 % were flagged before, 87 % now; of 500 unchanged ones, 4 more
    than before."""
    rng = np.random.default_rng(1)
    runs = [_after_confirmed(rng, 1.0, 0.15, back=True) for _ in range(500)]
    assert sum(level.flagged for level, _ in runs) < 0.65 * len(runs)  # against the new level
    assert sum(told.flagged for _, told in runs) > 0.85 * len(runs)
    told = next(told for level, told in runs if told.flagged and not level.flagged)
    assert told.direction == "decrease" and told.score >= 1, told
    assert "back at the level before the change confirmed at r9" in told.reason, told.reason
    unchanged = [_after_confirmed(rng, 1.0, 0.15, back=False) for _ in range(500)]
    added = sum(told.flagged and not level.flagged for level, told in unchanged)
    assert added <= 10, added


@pytest.mark.parametrize(("step", "between"), [(0.05, 0.03), (0.05, 0.15), (0.2, 0.06)])
def test_an_unchanged_revision_after_a_small_confirmed_change_is_seldom_told_a_return(
    step, between
) -> None:
    """The price: where the confirmed step is small beside the noise, an unchanged revision is
    now and then nearer the level before it: flagged as a return, it restarts the baseline at
    an unchanged revision until the revisions after it drop it. At most 7.5 points more often
    flagged than against the new level alone (2.6-7.1 here)."""
    rng = np.random.default_rng(1)
    runs = [_after_confirmed(rng, step, between, back=False) for _ in range(1000)]
    added = sum(told.flagged and not level.flagged for level, told in runs)
    assert added <= 75, added
