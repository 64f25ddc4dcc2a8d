"""Confirmation by history: does a change flagged at one revision hold in the revisions after it?

One revision's executions can move for reasons that are not the code (a busy spell the
disturbance check did not catch, a cache, a slow disk); the next revisions of unchanged code then
return to the old level. Perfherder waits for a "fore window" of later results before it shows an
alert, Otava's E-divisive looks at the whole history; Redline does the same where it cannot run
the revision again (imported results, a commit that no longer builds, a team that will not spend
the machine time): a flagged change is *suspected* until ``wait`` later revisions measured the
series, then it *holds* when those revisions stay on the new side of the old level, at least
half-way to the flagged one, and is *dropped* (a spike, its figures kept) when they do not.
A change is dropped too when its new level is not new (`seen_before`): the series moved between
the two levels again and again in the revisions before it, as a bimodal benchmark does (SAP's
"High deviation" series), so later revisions at the new level say nothing.

Levels are medians of one value per execution (`redline.detect.execution_shift`'s view of a
revision), or means for counts of rare events, which are mostly zero.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from redline.detect.median_shift import MAD_TO_SD, median, median_shift

#: Later revisions a flagged change must hold over before it is a regression (the default of a
#: component's ``confirm_revisions``; 0 makes every flagged change a regression at once).
DEFAULT_CONFIRM_REVISIONS = 2
#: Pairs of re-runs (baseline, candidate) a flagged revision gets when its component says nothing
#: (the default of ``confirm_pairs``; 0 confirms by the later revisions alone). Two: a first pair
#: that does not show the change drops it after two runs, a change holds when both show it.
#: Chosen by `bench_verdicts` (docs/detection.md, "End to end through the service").
DEFAULT_CONFIRM_PAIRS = 2
#: The share of the flagged step the later revisions must keep.
HOLD_SHARE = 0.5
#: Revisions before a flagged one that `seen_before` looks at.
LOOKBACK = 30
#: A new level is not new when at least this share of the values of the `LOOKBACK` revisions
#: before it were already beyond half-way to it, in at least `SEEN_STRETCHES` separate
#: stretches (a level the series visited once, as before an improvement that was reverted, is
#: new again). Chosen between the changes that the corpora's defaults find (at most 5.5 % of
#: such values, in at most 2 stretches; SAP's too) and the false alarms that history
#: confirmation let through on SAP's bimodal series (14-75 %, in 2-38 stretches; those at 15 %
#: or more in 12 or more are dropped). docs/detection.md, "As change points".
SEEN_SHARE = 0.10
SEEN_STRETCHES = 3
#: ... and further from the old level than this many robust standard deviations of the baseline
NOISE_SDS = 3.0

SUSPECTED, HELD, DROPPED = "suspected", "held", "dropped"
#: how the reason of a change its pairs confirmed begins (the history's says "held: ...")
BY_PAIRS = "confirmed by"


@dataclass(frozen=True)
class Hold:
    """``state``: `SUSPECTED` (not enough later revisions yet), `HELD` or `DROPPED`;
    ``kept``: the share of the flagged step the later revisions kept (NaN while suspected)."""

    state: str
    reason: str
    kept: float = math.nan


def _level(values: Sequence[float] | np.ndarray, count: bool) -> float:
    array = np.asarray(values, dtype=float)
    array = array[np.isfinite(array)]
    if not array.size:
        return math.nan
    return float(array.mean() if count else np.median(array))


def _pct(value: float, base: float) -> str:
    return f"{100 * (value - base) / abs(base):+.1f} %" if base else f"{value - base:+.3g}"


@dataclass(frozen=True)
class Seen:
    """How much of a series' past was already at a flagged new level: ``values`` looked at,
    the ``share`` of them there (`seen_before`), in ``stretches`` separate runs."""

    values: int
    share: float
    stretches: int

    @property
    def before(self) -> bool:
        return self.share >= SEEN_SHARE and self.stretches >= SEEN_STRETCHES


def seen_before(
    past: Sequence[float] | np.ndarray, baseline: Sequence[float] | np.ndarray, new: float
) -> Seen:
    """Where ``past`` (the values of the revisions before the flagged one, in order) stood
    against the step from the ``baseline``'s level to ``new``: a value counts when it is
    beyond half-way to the new level and further from the old than `NOISE_SDS` robust standard
    deviations of the baseline, so that the old level's own noise does not count (a noisy
    series' small real step has many past values beyond half-way; a bimodal one's large
    step has them in its other mode)."""
    values = np.asarray(past, dtype=float)
    values = values[np.isfinite(values)]
    base = np.asarray(baseline, dtype=float)
    base = base[np.isfinite(base)]
    if not values.size or not base.size:
        return Seen(int(values.size), 0.0, 0)
    old = median(base)
    if new == old:
        return Seen(int(values.size), 0.0, 0)
    reach = max(abs(new - old) / 2, NOISE_SDS * MAD_TO_SD * median(np.abs(base - old)))
    beyond = values > old + reach if new > old else values < old - reach
    starts = np.flatnonzero(np.diff(np.concatenate([[0], beyond.astype(np.int8)])) == 1)
    return Seen(int(values.size), float(beyond.mean()), int(starts.size))


def hold(
    baseline: Sequence[float] | np.ndarray,
    flagged: Sequence[float] | np.ndarray,
    following: Sequence[Sequence[float] | np.ndarray],
    wait: int = DEFAULT_CONFIRM_REVISIONS,
    *,
    count: bool = False,
    past: Sequence[float] | np.ndarray = (),
) -> Hold:
    """Whether a change from ``baseline`` (its execution values) to ``flagged`` (the flagged
    revision's) holds over the revisions after it, ``following`` (each one's execution values,
    oldest first; only the first ``wait`` count), and is new: ``past``, the execution values of
    the `LOOKBACK` revisions before the flagged one, oldest first, did not keep returning to
    the new level (`seen_before`; not for counts of rare events, whose level is a rate)."""
    if wait <= 0:
        return Hold(HELD, "confirmation by history is off (confirm_revisions = 0)", 1.0)
    after = [np.asarray(v, dtype=float) for v in following[:wait] if len(v)]
    if len(after) < wait:
        return Hold(
            SUSPECTED,
            f"waiting for {wait - len(after)} more revision(s) after it to measure the series "
            f"(holds when {wait} later revisions keep the new level)",
        )
    old, new = _level(baseline, count), _level(flagged, count)
    later = _level(np.concatenate(after), count)
    step = new - old
    if not all(map(math.isfinite, (old, new, later))) or step == 0:
        return Hold(DROPPED, "the levels cannot be compared (no finite values, or no step)", 0.0)
    kept = (later - old) / step
    figures = (
        f"flagged at {_pct(new, old)}, the next {wait} revision(s) at {_pct(later, old)} "
        f"of the old level ({100 * kept:.0f} % of the step kept)"
    )
    if kept < HOLD_SHARE:
        return Hold(DROPPED, f"not confirmed, returned towards the old level: {figures}", kept)
    seen = seen_before(() if count else past, baseline, new)
    if seen.before:
        return Hold(
            DROPPED,
            f"not confirmed, the level is not new: {figures}, but {100 * seen.share:.0f} % of "
            f"the {seen.values} values of the revisions before it were there already (beyond "
            f"half-way, and beyond the old level's noise), in {seen.stretches} separate "
            "stretches: the series moves between levels",
            kept,
        )
    return Hold(HELD, f"held: {figures}", kept)


#: How a reason begins when the re-runs could not decide a change (none ran, too few gave a
#: value, a count, a series they did not measure): the history decides then
UNDECIDED = "re-runs could not decide"
#: ... and how such a reason hands the change to the history
LATER_DECIDE = "the later revisions will confirm it instead"
#: The share of complete pairs that must show the change for it to be confirmed by re-runs.
PAIRS_SHARE = 2 / 3
#: A pair shows a change when its candidate moved the flagged way by more than this many
#: standard deviations of a pair's difference: two executions' noise, sqrt(2) times the robust
#: spread of the baseline's execution values (`relative_noise`). With unchanged code one pair
#: in 15 passes that bar (normal noise), two in a row one in 225. The flagged step itself is no
#: bar: a change flagged on one execution is flagged *because* its noise pushed it up (the
#: winner's curse), and half of it is often more than the change. At a threshold of 4, CPU
#: +30 % was flagged +52.5 % on one execution and dropped when its pair showed +14.5 %
#: (`bench_verdicts`, verdicts-threshold4-pairs2-sets.json).
PAIR_SDS = 1.5
#: ... and by at least this much (half of `ExecutionShift`'s least effect worth reporting), so
#: that a series with next to no noise (a memory size) does not confirm a move of a few bytes.
PAIR_FLOOR = 0.025


def relative_noise(baseline: np.ndarray | Sequence[float], rel_scale: float = 0.01) -> float:
    """The noise of one execution value of ``baseline`` relative to its level: the robust
    spread `ExecutionShift` judges against (at least its floor), over the median; NaN without
    finite values or with a level of 0."""
    values = np.asarray(baseline, dtype=float)
    values = values[np.isfinite(values)]
    if not values.size:
        return math.nan
    shift = median_shift(values, values, rel_scale)
    return shift.spread / abs(shift.before) if shift.before else math.nan


def pair_bar(effect: float, noise: float) -> float:
    """How far (relative, the flagged way) a pair's candidate must move from its baseline to
    show a change flagged by ``effect``: `PAIR_SDS` pair noises, at least `PAIR_FLOOR`, where
    the baseline's ``noise`` is known (`relative_noise`); else `HOLD_SHARE` of the flagged step."""
    if not math.isfinite(noise):
        return HOLD_SHARE * abs(effect)
    return max(PAIR_SDS * math.sqrt(2) * noise, PAIR_FLOOR)


#: how the reason of a verdict moved back to the revision that made the change begins
#: (`redline.worker.found_late`), and the mark that it is not moved again
FOUND_LATE = "found a revision late"
#: how the reason of a change the later revisions' level found at an earlier revision begins
#: (`redline.worker.held_level`)
LEVEL_HELD = "found later"
#: the reasons of changes found after their revision was judged, whose own runs missed them:
#: confirmed by pairs of their own or not at all, and never moved back again
FOUND_LATER = (FOUND_LATE, LEVEL_HELD)


@dataclass(frozen=True)
class Earlier:
    """Where a flagged revision's pairs put its baseline revision: their runs of it ``moved``
    (relative) from the level of its own baseline, beyond ``bar``."""

    moved: float
    bar: float


def already_moved(
    reruns: Sequence[float] | np.ndarray,
    own_baseline: Sequence[float] | np.ndarray,
    direction: str,
    rel_scale: float = 0.01,
) -> Earlier | None:
    """Whether a change flagged at a revision, which its pairs did not show against its baseline
    revision, came at that baseline revision instead: whether the pairs' runs of it (``reruns``)
    sit the flagged way beyond `pair_bar` of the noise of *its* baseline (``own_baseline``, its
    execution values), their median against that baseline's. None when they do not, or when
    either has no finite value.

    With one execution a revision, a change's own run can miss it (its noise pulled it back);
    the change then pools into the baseline and is flagged at the next, unchanged revision,
    whose pairs rightly show nothing: both of their revisions have it (`bench_verdicts`: CPU
    +10 % and +30 % were each flagged a revision late and dropped)."""
    runs = np.asarray(reruns, dtype=float)
    runs = runs[np.isfinite(runs)]
    base = np.asarray(own_baseline, dtype=float)
    base = base[np.isfinite(base)]
    if not runs.size or not base.size:
        return None
    level = median(base)
    noise = relative_noise(base, rel_scale)
    if not level or not math.isfinite(noise):
        return None
    moved = (median(runs) - level) / abs(level)
    bar = pair_bar(moved, noise)
    return Earlier(moved, bar) if _shows(moved, direction, bar) else None


def _complete(pairs: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    return [(b, c) for b, c in pairs if math.isfinite(b) and math.isfinite(c) and b != 0]


def _moves(complete: Sequence[tuple[float, float]]) -> list[float]:
    return [(c - b) / abs(b) for b, c in complete]


def pair_moves(pairs: Sequence[tuple[float, float]]) -> list[float]:
    """Each complete pair's move of its candidate from its baseline, relative."""
    return _moves(_complete(pairs))


def _shows(move: float, direction: str, bar: float) -> bool:
    """Whether one pair's relative move shows a change flagged ``direction``: beyond ``bar``
    (`pair_bar`) that way."""
    sign = 1.0 if direction == "increase" else -1.0
    return sign * move >= bar


def _needed(pairs: int) -> int:
    """How many pairs must show a change for ``pairs`` of them to confirm it (2 of 2, 2 of 3)."""
    return max(1, math.ceil(PAIRS_SHARE * pairs))


def _outcome(shown: int, lacking: int, wanted: int) -> str:
    """`HELD` when ``shown`` pairs reach what ``wanted`` need, `SUSPECTED` (undecided) when the
    ``lacking`` ones, which gave no value, could have, `DROPPED` otherwise."""
    needed = _needed(wanted)
    if shown >= needed:
        return HELD
    return SUSPECTED if shown + lacking >= needed else DROPPED


def pairs_decided(
    pairs: Sequence[tuple[float, float]],
    direction: str,
    effect: float,
    pending: int,
    noise: float = math.nan,
    wanted: int | None = None,
) -> bool:
    """Whether the ``pairs`` that ran decide `pairs_hold` whatever the ``pending`` ones show,
    or whether they run at all: then those need not run (with 3 pairs, two that agree decide).
    The verdict is the one all the pairs would give, judged as `pairs_hold` judges them with
    ``wanted`` (default: every pair, those to run included); only machine time is saved."""
    ran = _complete(pairs)
    complete = len(ran)
    bar = pair_bar(effect, noise)
    shown = sum(_shows(move, direction, bar) for move in _moves(ran))
    wanted = len(pairs) + pending if wanted is None else wanted
    outcomes = set()
    for more in range(pending + 1):  # the pending pairs that give a value
        final = max(wanted, complete + more)  # as `pairs_hold` counts what is wanted
        for more_shown in range(more + 1):
            outcomes.add(_outcome(shown + more_shown, final - complete - more, final))
    return len(outcomes) == 1


def pairs_hold(
    pairs: Sequence[tuple[float, float]],
    direction: str,
    effect: float,
    wanted: int,
    noise: float = math.nan,
) -> Hold:
    """Confirmation by re-running: ``pairs`` of (baseline, candidate) values, each pair run
    back to back on one host, against a change flagged ``direction`` by ``effect`` (relative),
    on a series whose execution values vary by ``noise`` (relative, `relative_noise` of the
    baseline; NaN: unknown). A pair shows the change when the candidate moved the flagged way
    beyond `pair_bar`; the change holds when at least `PAIRS_SHARE` of the complete pairs show
    it. ``wanted``: the pairs that were queued (a missing one is named in the reason)."""
    complete = _complete(pairs)
    if not complete:
        return Hold(
            SUSPECTED,
            f"{UNDECIDED}: none of the {wanted} confirmation pair(s) gave a value of it; the "
            "later revisions will confirm it instead",
        )
    sign = 1.0 if direction == "increase" else -1.0
    bar = pair_bar(effect, noise)
    moves = _moves(complete)
    shown = sum(_shows(move, direction, bar) for move in moves)
    moved = ", ".join(f"{100 * move:+.1f} %" for move in moves)
    lacking = max(0, wanted - len(complete))  # incomplete: NaN, or never ran
    missing = (
        f"; {lacking} more pair(s) gave no value of it (a run measured while the host was busy, or "
        "one that did not run)"
        if lacking
        else ""
    )
    why = f"{PAIR_SDS:g} sd of a pair's noise" if math.isfinite(noise) else "half the flagged step"
    figures = (
        f"{shown} of {len(complete)} pairs (candidate against baseline, back to back on one "
        f"host: {moved}; flagged {100 * sign * abs(effect):+.1f} %; a pair shows it beyond "
        f"{100 * sign * bar:+.1f} %, {why}){missing}"
    )
    wanted = max(wanted, len(complete))
    outcome = _outcome(shown, wanted - len(complete), wanted)
    if outcome == HELD:
        return Hold(HELD, f"{BY_PAIRS} {figures}", shown / len(complete))
    if outcome == SUSPECTED:  # two that agree decide: one alone does not (a trial's did)
        return Hold(
            SUSPECTED,
            f"{UNDECIDED}: {_needed(wanted)} pairs must show it, and {figures}; the later "
            "revisions will confirm it instead",
        )
    return Hold(DROPPED, f"not confirmed: the change showed in {figures}", shown / len(complete))
