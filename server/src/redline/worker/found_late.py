"""A change found a revision late, moved to the revision that made it.

With one execution a revision, a change's own run can miss it (its noise pulled it back under
the threshold); the change then pools into the baseline and is flagged at the next revision,
whose code did not change. That revision's confirmation pairs run it against the changed
revision and rightly show nothing, so the flag is dropped and the change is lost
(`bench_verdicts`: CPU +10 % and +30 % each went so). The same pairs' runs of the baseline
revision do say where the change is (`redline.detect.confirmation.already_moved`): when they sit
beyond the noise of *its* baseline, the flagged way, its verdict of the series becomes a
suspected change, grouped into a regression of its own and confirmed by pairs against its own
baseline revision, as any flagged change is (`redline.worker.confirm_runs`). Only where such
pairs can be had (an agent measured the revision): its own runs missed the change, so the later
revisions cannot settle it by history, which drops it if its pairs could not run.

The moved verdict outlives the revision's own verdicts being stored again, by new results or a
re-analysis (both judge it on its own executions, which did not show the change): `still_moved`
keeps it unless it is now judged a change on its own. A regression it opened keeps its id.

Once only: a change moved back (its reason begins `FOUND_LATE`), or found at its revision by
the level the later revisions hold (`redline.worker.held_level`), is not moved again, or a host
that slowed down since the history was measured would walk every dropped flag back through it,
two runs a revision.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from redline.detect.confirmation import (
    FOUND_LATE,
    FOUND_LATER,
    HOLD_SHARE,
    PAIR_SDS,
    Earlier,
    already_moved,
)
from redline.detect.execution_shift import STEP_SIDE
from redline.detect.result import CHANGE, NO_CHANGE, NOT_ENOUGH_DATA, waits_for_history
from redline.server.models import Detection, Revision
from redline.worker.confirmation import baseline_and_own, baseline_values
from redline.worker.grouping import group_detection
from sqlalchemy import or_, select
from sqlalchemy.orm import Session

#: how the reasons of the two moves go on after "found a revision late: rN's ": by the pairs'
#: runs of the baseline revision (`move_back`), by its own runs (`move_back_unjudged`)
PAIRS_RAN = "confirmation pairs ran it"
OWN_RUNS = "confirmation pairs showed nothing against it, and its own run(s)"


def _of_baseline(session: Session, detection: Detection) -> Detection | None:
    """The verdict of ``detection``'s series and method at its baseline revision; None for a
    change moved once already (found late), or one without a baseline revision."""
    if detection.reason.startswith(FOUND_LATER) or detection.baseline_revision_id is None:
        return None
    return session.scalar(
        select(Detection).where(
            Detection.series_id == detection.series_id,
            Detection.revision_id == detection.baseline_revision_id,
            Detection.method == detection.method,
        )
    )


def _figures(found: Earlier, direction: str) -> tuple[str, str]:
    """How far it moved and the bar it passed, in words ("+18.2 %", "+4.0 %")."""
    sign = 1.0 if direction == "increase" else -1.0
    return f"{100 * found.moved:+.1f} %", f"{100 * sign * found.bar:+.1f} %"


def _changed(earlier: Detection, detection: Detection, found: Earlier, reason: str) -> None:
    """``earlier`` made a suspected change, the way ``detection`` was flagged, by ``found``."""
    earlier.verdict, earlier.flagged, earlier.direction = CHANGE, True, detection.direction
    earlier.effect, earlier.score, earlier.p_value = found.moved, abs(found.moved / found.bar), None
    earlier.reason = reason


def move_back(
    session: Session, detection: Detection, candidate: Revision, reruns: Sequence[float]
) -> Revision | None:
    """The baseline revision of ``detection`` (a change of ``candidate`` its pairs dropped) when
    the pairs' runs of it (``reruns``) show the change there: its verdict of the series is then
    a suspected change in a regression, and ``detection``'s reason says where the change went
    (as it does again when these pairs moved it before). None when they do not, or when it was
    moved once already or judged a change already."""
    earlier = _of_baseline(session, detection)
    if earlier is None:
        return None
    if (
        earlier.reason.startswith(f"{FOUND_LATE}: {candidate.title}'s {PAIRS_RAN}")
        and earlier.effect
    ):
        _went(detection, earlier.revision, earlier.effect)  # moved by these pairs before
        return None
    if earlier.verdict != NO_CHANGE:
        return None  # a change already (its own confirmation decides), or never judged
    own = baseline_values(session, earlier)
    found = None if own is None else already_moved(reruns, own, detection.direction)
    if found is None:
        return None
    revision = earlier.revision
    was = f"{100 * earlier.effect:+.1f} %" if earlier.effect is not None else "no figure"
    moved, bar = _figures(found, detection.direction)
    _changed(
        earlier,
        detection,
        found,
        f"{FOUND_LATE}: {candidate.title}'s {PAIRS_RAN} {moved} from its own "
        f"baseline (beyond {bar}, {PAIR_SDS:g} sd of a pair's noise) and {candidate.title} no "
        f"further; its own run(s) had shown {was}, no change",
    )
    group_detection(session, earlier, revision)
    _went(detection, revision, found.moved)
    return revision


def move_back_unjudged(
    session: Session, detection: Detection, candidate: Revision
) -> Revision | None:
    """The baseline revision of ``detection`` (a change of ``candidate`` its pairs dropped)
    when that revision could not be judged when measured (too few baseline values) and its own
    run(s) sit beyond `PAIR_SDS` of its baseline's noise, the flagged way: the change came
    with it, before ``candidate``. Its verdict then becomes a suspected change, which its own
    pairs decide (`confirm_found_late`). A new user's +67 % CPU, made while the baseline
    restarted after a confirmed tripling, was flagged a revision late, dropped by pairs of
    identical code, and never a regression. Its own runs, not the pairs': the pairs ran the
    flagged sets alone, whose level is not the suite's (`move_back` is for pairs that ran the
    suite as far as their sets)."""
    earlier = _of_baseline(session, detection)
    if (
        earlier is not None
        and earlier.effect
        and earlier.reason.startswith(f"{FOUND_LATE}: {candidate.title}'s {OWN_RUNS}")
    ):  # moved when these pairs were judged before (a re-analysis judges them again)
        _went(detection, earlier.revision, earlier.effect, "own run(s)")
        return None
    if (
        earlier is None
        or earlier.verdict != NOT_ENOUGH_DATA
        or not waits_for_history(earlier.reason)
    ):
        return None
    own, runs = baseline_and_own(session, earlier)
    if own is None or runs is None or len(own) < STEP_SIDE:
        return None  # a baseline of one or two values says nothing of its noise
    found = already_moved(runs, own, detection.direction)
    # the step the dropped flag saw, not a few per cent the short baseline's noise allows
    if found is None or abs(found.moved) < HOLD_SHARE * abs(detection.effect or 0.0):
        return None
    revision = earlier.revision
    moved, bar = _figures(found, detection.direction)
    _changed(
        earlier,
        detection,
        found,
        f"{FOUND_LATE}: {candidate.title}'s {OWN_RUNS} sat {moved} from its own baseline "
        f"(beyond {bar}, {PAIR_SDS:g} sd of a pair's noise), which had too few values to judge "
        "them when they were measured",
    )
    group_detection(session, earlier, revision)
    _went(detection, revision, found.moved, "own run(s)")
    return revision


def _went(
    detection: Detection, revision: Revision, moved: float, runs: str = "runs in these pairs"
) -> None:
    detection.confirmation_reason += (
        f"; {revision.title}'s {runs} were already at the new level "
        f"({100 * moved:+.1f} % on its own baseline): the change is {revision.title}'s, re-run "
        "against its own baseline"
    )


def still_moved(
    session: Session, revision_id: int, fresh: Iterable[tuple[int, str, str, str]]
) -> dict[tuple[int, str], int]:
    """Of the revision's verdicts found late (moved back to it, or a level held after it:
    `FOUND_LATER`), those that storing its ``fresh`` verdicts
    ((series id, method, verdict, reason) each) keeps, by (series id, method): those it judges "no
    change" again on its own executions, which missed the change, or "not enough data" (its
    baseline still too short, `move_back_unjudged`). The fresh verdicts of those series and
    methods are not stored."""
    moved = {
        (series_id, method): ident
        for ident, series_id, method in session.execute(
            select(Detection.id, Detection.series_id, Detection.method).where(
                Detection.revision_id == revision_id,
                or_(*(Detection.reason.startswith(found) for found in FOUND_LATER)),
            )
        )
    }
    if not moved:  # nearly always
        return {}
    return {
        (series_id, method): moved[(series_id, method)]
        for series_id, method, verdict, reason in fresh
        if (series_id, method) in moved
        and (verdict == NO_CHANGE or (verdict == NOT_ENOUGH_DATA and waits_for_history(reason)))
    }
