"""Judging a revision whose baseline restarted at a flag and is too short to judge by.

Under the ``recent`` baseline a flag restarts the baseline at once (`redline.detect.baseline`):
the revisions after a real change are compared with the new level, not flagged again. Until
``confirm_revisions`` revisions after the flag have measured the series, though, that new level
is the flagged revision's own values, too few to judge by with one execution a revision: every
revision there was "not enough data", whether the flag was a real change or noise. A trial saw
a README-only commit flagged as an improvement make the next two commits' CI verdicts blind
("skipped: the baseline has 3, needs 6"); a regression made there would have passed unjudged.

So where that restarted baseline is too short, the revision is judged against the level before
the flag as well (`past_suspected`: the flagged revision's own baseline, read past any flag at
most ``confirm_revisions`` before it; the flagged values left out, which would pull that level
towards the suspected one). A change for the worse (or better) against it stands, and so does
"no change"; only a change in the direction of the one suspected, which is that change holding
(or a further step the short new level cannot tell from it), stays "not enough data", its
reason saying so, unless it moved back from the flag's own level (`after_flag`). Whether the
flag was a change is still settled by its pairs or by the later revisions
(`redline.detect.confirmation`). Once they held it, the new level is judged with the noise of
the level before it (`at_new_level`) until it holds enough values alone.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial

import numpy as np
from redline.detect.execution_shift import STEP_SIDE, ExecutionShift
from redline.detect.median_shift import median
from redline.detect.methods import Detector
from redline.detect.result import CHANGE, Detection, direction_of, waits_for_history
from redline.detect.verdict import floored, judge_series

#: how the reason of a verdict judged against the level before an undecided flag begins
#: ("flagged", not "suspected": the flag's own pairs may have confirmed it meanwhile, and a
#: trial read "the change suspected at X" beside "#1 confirmed")
BEFORE_SUSPECTED = "judged against the level before the change flagged at"
#: what the reason of a revision that shows an undecided flag's change says (`past_suspected`)
SHOWS_THAT_CHANGE = "shows that change"
#: how the reason of a verdict judged against a short new level (`at_new_level`) begins
AT_NEW_LEVEL = "judged against the new level since the change at"
#: what a verdict after a flag was judged against (`after_flag`): the values from the flag on,
#: the level before the flag, or the level before a short confirmed one (`returned_to_older`)
RESTARTED, BEFORE, OLDER = "restarted", "before", "older"
#: how much nearer the level before a confirmed change than its short new level a revision must
#: be to be flagged as a return (`moved_back`), and how far towards a flag against the new level
#: (a share of the threshold). Chosen on a simulation of 1,000 revisions a case (three
#: executions a revision, 3, 6 and 15 % of noise between revisions, steps of 5, 20 and 100 %,
#: as `tests/unit/test_confirmed_levels.py`'s `_after_confirmed`): a revert of a +100 % step is
#: flagged 89-100 % of the time (57-100 % before), of a +20 % one 24-98 % (8-80 %), and an
#: unchanged revision after a step 0-8 points more often than before. Only
#: changes for the worse run pairs, so a return is always for the better: it alarms no one and
#: runs no pairs, and a false one restarts the baseline at an unchanged revision, a flag the
#: revisions after it decide
MOVED_BACK_NEARER, MOVED_BACK_Z = 2.0, 0.5


@dataclass(frozen=True)
class LevelBefore:
    """The level before a flag: ``values``, the flagged revision's own baseline read past any
    flag the revisions after it have not yet decided. Where that is a short level its pairs
    confirmed (at revision ``confirmed_at``), ``noise`` is the nearest level before it long
    enough to judge by, whose spread it is judged with (`Baselines._level_before`)."""

    values: np.ndarray
    noise: np.ndarray | None = None
    confirmed_at: str = ""

    @property
    def spread_from(self) -> np.ndarray:
        """The values whose spread a revision is judged with against this level or after it."""
        return self.values if self.noise is None else self.noise

    def judge(self, detector: Detector, counter: str, candidate: np.ndarray) -> Detection:
        """``candidate`` judged against this level: as the detector judges a baseline, or, where
        it is a short confirmed level, as `at_new_level`, with ``noise``."""
        found = judge_series(detector, counter, self.values, candidate)
        if self.noise is None:
            return found
        return at_new_level(
            found, detector, counter, self.values, self.noise, candidate, self.confirmed_at, 1
        )


@dataclass(frozen=True)
class Flagged:
    """A revision judged after the flag at revision ``at`` (``restarted``: the values from it
    on; ``before``: the level before it): what `moved_back` and `returned_to_older` ask."""

    detector: Detector
    counter: str
    restarted: np.ndarray
    before: LevelBefore
    candidate: np.ndarray
    at: str

    def moved_back(self, level: Detection) -> Detection:
        """``level``, the verdict against the short new level of a change its pairs confirmed
        at ``at`` (its values ``restarted``), or, where that showed no change but the revision
        is back at the level before the change, a flag of that return: for the better (only
        changes for the worse are confirmed by pairs), so the revisions after it decide it.
        Back: no change against ``before``; its median `MOVED_BACK_NEARER` times as near that
        level as the new one, and at least `MOVED_BACK_Z` of the way to a flag against the new
        level (``level.score``), by at least the detector's relative floor and the counter's
        absolute one (`floored`, as every flag). A fourth trial's revert of a
        confirmed regression (x2 on a noisy component) was "no change -49.5 %" against the
        regression's three values (score 0.95), was pooled with them into the next commit's
        baseline, and the reland after it, +29.6 %, passed as "no change". The score is the
        smaller of the two margins, each over its bar, so at least 1 when flagged, as every
        method's."""
        if not level.decided or level.flagged or not isinstance(self.detector, ExecutionShift):
            return level
        finite = [v[np.isfinite(v)] for v in (self.restarted, self.before.values, self.candidate)]
        if not all(len(v) for v in finite):  # a level of no finite value: nothing to be near
            return level
        new, old, now = (median(v) for v in finite)
        if (
            direction_of(now - new) == direction_of(new - old)
            or abs(level.effect) < self.detector.min_effect
        ):
            return level
        nearer = abs(now - new) / max(abs(now - old), 1e-12)
        score = min(nearer / MOVED_BACK_NEARER, level.score / MOVED_BACK_Z)
        if score < 1:
            return level
        back = self.before.judge(self.detector, self.counter, self.candidate)
        if not back.decided or back.flagged:
            return level
        times = f"{nearer:.1f} times" if nearer < 100 else "over 100 times"
        note = (
            f"back at the level before the change confirmed at {self.at} (no change against "
            f"it, {back.effect:+.1%}; {times} as near it as the new level): flagged as a "
            "return, which the revisions after it decide"
        )
        flagged = replace(level, verdict=CHANGE, score=score, reason=f"{level.reason}; {note}")
        return floored(flagged, self.counter, finite[0], finite[2])

    def returned_to_older(self) -> Detection | None:
        """Where the flag at ``at`` (its values ``restarted``) came right after a short level
        its pairs confirmed and returned to the level before that one (``before.noise``: a
        regression reverted), ``candidate`` judged against that older level, long enough to
        judge by; None otherwise. A trial's commit after such a revert, +30 % over the level the
        revert returned to, was judged against the confirmed level and the revert's three
        values: "not enough data" in three parameter sets and "no change -34.2 %" (score 0.997)
        in the fourth, for lack of power, and then pooled unflagged; an unchanged one was "not
        enough data" too."""
        if self.before.noise is None:
            return None
        flag = judge_series(
            self.detector,
            self.counter,
            self.before.noise,
            self.restarted[np.isfinite(self.restarted)],
        )
        if not flag.decided or flag.flagged:
            return None
        found = judge_series(self.detector, self.counter, self.before.noise, self.candidate)
        if not found.decided:
            return None
        note = (
            "judged against the level before the change confirmed at "
            f"{self.before.confirmed_at}, to which the change flagged at {self.at} returned"
        )
        return replace(found, reason=f"{found.reason}; {note}" if found.reason else note)


def after_flag(
    found: Detection,
    detector: Detector,
    counter: str,
    restarted: np.ndarray,
    before: LevelBefore,
    candidate: np.ndarray,
    at: str,
    held: bool,
    confirmed: bool = False,
) -> tuple[Detection, str]:
    """The verdict of a revision whose baseline restarted at the flag at revision ``at``
    (``restarted``: the values from it on; ``before``: the level before it), as the worker and
    the offline evaluation both judge it: `at_new_level` once the revisions after the flag
    ``held`` it or its pairs ``confirmed`` it (then however few its values, and a return to
    the level before it is told: `moved_back`), else `past_suspected`. Returns the verdict and
    what it was judged against: `RESTARTED`, `BEFORE` (``before.values``) or `OLDER`
    (``before.noise``: `returned_to_older`)."""
    context = Flagged(detector, counter, restarted, before, candidate, at)
    if held or confirmed:
        least = 1 if confirmed else STEP_SIDE
        level = at_new_level(
            found, detector, counter, restarted, before.spread_from, candidate, at, least
        )
        if confirmed and level is not found:
            level = context.moved_back(level)
        return level, RESTARTED
    if not found.decided and waits_for_history(found.reason):
        older = context.returned_to_older()
        if older is not None:  # judged against a long level, not the short confirmed one
            return older, OLDER
    judge = partial(before.judge, detector, counter, candidate)
    verdict, judged_before = past_suspected(found, judge, restarted, before.values, at)
    if SHOWS_THAT_CHANGE not in verdict.reason:
        return verdict, BEFORE if judged_before else RESTARTED
    # It shows the flag's change against the level before it: judged against the flag's own
    # level too, as once a change held, a change the other way from the flag's stands (a part
    # of it undone, or a further step), against the flag's revision, whose pairs settle which
    # level it left. A trial's commit that raised the CPU by 19 % right after an improvement was
    # flagged (three executions a revision; still 28.8 % under the level before it) was "not
    # enough data", passed CI and was pooled into the new level: never flagged. The flag's own
    # values may be one (one execution a revision): its noise is the level before it's, and z
    # counts the one value as such. A spike's return to the level before it shows no change
    # there, and is not judged here.
    undone = at_new_level(
        verdict, detector, counter, restarted, before.spread_from, candidate, at, 1
    )
    flagged = direction_of(median(restarted[np.isfinite(restarted)]) - median(before.values))
    if undone.flagged and undone.direction != flagged:
        note = (
            f"{BEFORE_SUSPECTED} {at} it still shows that change: a part of it undone, or a "
            "further step; the revisions after it have not yet decided it"
        )
        return replace(undone, reason=f"{undone.reason}; {note}"), RESTARTED
    return verdict, RESTARTED


def past_suspected(
    found: Detection,
    judge: Callable[[], Detection],
    restarted: np.ndarray,
    earlier: np.ndarray,
    at: str,
) -> tuple[Detection, bool]:
    """The verdict of a revision whose baseline restarted at a flag still undecided (at
    revision ``at``): ``found``, judged against ``restarted`` (the values from that flag on),
    or, where that baseline was too short, ``judge()``: the revision judged against the level
    before the flag (``earlier``, its values). Returns the verdict and whether it was judged
    against ``earlier``."""
    restarted, earlier = restarted[np.isfinite(restarted)], earlier[np.isfinite(earlier)]
    if (
        found.decided
        or not waits_for_history(found.reason)
        or not (len(restarted) and len(earlier))
    ):
        return found, False
    old = judge()
    if not old.decided:
        return found, False
    suspected = direction_of(median(restarted) - median(earlier))
    if old.flagged and old.direction == suspected:
        return replace(
            found,
            reason=f"{found.reason}; against the level before the change flagged at {at} it "
            f"{SHOWS_THAT_CHANGE} ({old.effect:+.1%}): the new level is too short to judge by "
            "until the revisions after it decide",
        ), False
    note = (
        f"{BEFORE_SUSPECTED} {at}, which the revisions after it have not yet decided (the "
        f"level from it on has {len(restarted)} value(s), too few)"
    )
    return replace(old, reason=f"{old.reason}; {note}" if old.reason else note), True


def at_new_level(
    found: Detection,
    detector: Detector,
    counter: str,
    level: np.ndarray,
    earlier: np.ndarray,
    candidate: np.ndarray,
    at: str,
    least: int = STEP_SIDE,
) -> Detection:
    """The verdict of a revision whose baseline restarted at a change that held (at revision
    ``at``): ``found``, or, where that new level (``level``, its values, at least ``least``) was
    too short to judge by, `ExecutionShift.at_new_level` against it with the noise of the level
    before it (``earlier``: the values the flagged revision's own baseline holds, or
    `LevelBefore.spread_from`), and the counter's
    absolute floor. Without it, the revisions after a real change were "not enough data"
    until six values at the new level existed: with one execution a revision, a second change
    made in the five revisions after the first passed CI unjudged and was pooled into the new
    level. Only for `ExecutionShift`'s kind (one value an execution or a revision)."""
    if (
        found.decided
        or not waits_for_history(found.reason)
        or not isinstance(detector, ExecutionShift)
    ):
        return found
    judged = detector.at_new_level(level, earlier, candidate, least)
    if not judged.decided:
        return found
    judged = floored(judged, counter, level, candidate)
    note = (
        f"{AT_NEW_LEVEL} {at} ({len(level[np.isfinite(level)])} value(s)), with the noise of "
        "the level before it too"
    )
    return replace(judged, reason=f"{judged.reason}; {note}" if judged.reason else note)
