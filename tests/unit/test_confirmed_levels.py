"""A flag its pairs confirmed is a decided level (`redline.detect.baseline.CONFIRMED`), and a short
one is judged with the noise of the levels before it (`ExecutionShift.at_new_level` on several
levels). A trial's regression, confirmed by its pairs and reverted by the next commit, was read
past as a flag not yet decided: the commit after the revert was judged against the level before
the regression, and a +28 % step there was "not enough data" (`tests/integration/
test_suspected_level.py` has the whole history through the worker)."""

from __future__ import annotations

import numpy as np
import pytest
from redline.detect.baseline import CONFIRMED, take_recent
from redline.detect.execution_shift import ExecutionShift
from redline.detect.result import CHANGE, NO_CHANGE, NOT_ENOUGH_DATA


def _revisions(*flags: int) -> list[tuple[int, np.ndarray, int]]:
    """Revisions 0.. newest first, three values each, flagged as given."""
    return [(k, np.full(3, 10.0 + k), flag) for k, flag in enumerate(flags)]


@pytest.mark.parametrize(
    ("flags", "taken", "why"),
    [
        ((1, 0, 0, 0, 0, 0), [1, 2, 3, 4, 5], "a flag right before it, undecided: read past"),
        ((CONFIRMED, 0, 0, 0, 0, 0), [0], "confirmed by its pairs: the level starts there"),
        ((0, CONFIRMED, 0, 0, 0, 0), [0, 1], "the same one revision further back"),
    ],
)
def test_the_level_before_a_flag_is_not_read_past_a_flag_its_pairs_confirmed(
    flags, taken, why
) -> None:
    found = take_recent(_revisions(*flags), need=15, wait=2, past_undecided=True)
    assert found == taken, why


def test_a_short_level_is_judged_with_each_earlier_level_s_own_noise() -> None:
    """Levels of 20 and 40 (1 % noise each, four values), then a new level of 30 (three
    values): a candidate 10 % above it is a change with each level's residuals from its own
    median; pooled as one level, the gap between 20 and 40 would read as noise."""
    rng = np.random.default_rng(4)
    older, short = 40.0 * (1 + rng.normal(0, 0.01, 4)), 20.0 * (1 + rng.normal(0, 0.01, 4))
    level = 30.0 * (1 + rng.normal(0, 0.01, 3))
    judge = ExecutionShift().confirmed()
    raised = np.array([33.0])
    assert judge.at_new_level(level, [short, older], raised).verdict == CHANGE
    assert judge.at_new_level(level, np.concatenate([short, older]), raised).verdict == NO_CHANGE
    assert judge.at_new_level(level, [short, older], np.array([30.2])).verdict == NO_CHANGE
    # a level of one value says nothing of the noise: not counted towards the six needed
    few = judge.at_new_level(level, [short, older[:1]], raised)
    assert few.verdict == NOT_ENOUGH_DATA and "4 before it (needs 6)" in few.reason
