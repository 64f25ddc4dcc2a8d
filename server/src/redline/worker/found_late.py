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

from redline.detect.confirmation import FOUND_LATE, FOUND_LATER, PAIR_SDS, already_moved
from redline.detect.result import CHANGE, NO_CHANGE
from redline.server.models import Detection, Revision
from redline.worker.confirmation import baseline_values
from redline.worker.grouping import group_detection
from sqlalchemy import or_, select
from sqlalchemy.orm import Session


def move_back(
    session: Session, detection: Detection, candidate: Revision, reruns: Sequence[float]
) -> Revision | None:
    """The baseline revision of ``detection`` (a change of ``candidate`` its pairs dropped) when
    the pairs' runs of it (``reruns``) show the change there: its verdict of the series is then
    a suspected change in a regression, and ``detection``'s reason says where the change went
    (as it does again when these pairs moved it before). None when they do not, or when it was
    moved once already or judged a change already."""
    if detection.reason.startswith(FOUND_LATER) or detection.baseline_revision_id is None:
        return None
    earlier = session.scalar(
        select(Detection).where(
            Detection.series_id == detection.series_id,
            Detection.revision_id == detection.baseline_revision_id,
            Detection.method == detection.method,
        )
    )
    if earlier is None:
        return None
    if earlier.reason.startswith(f"{FOUND_LATE}: {candidate.title}'s ") and earlier.effect:
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
    sign = 1.0 if detection.direction == "increase" else -1.0
    moved, bar = f"{100 * found.moved:+.1f} %", f"{100 * sign * found.bar:+.1f} %"
    earlier.verdict, earlier.flagged, earlier.direction = CHANGE, True, detection.direction
    earlier.effect, earlier.score, earlier.p_value = found.moved, abs(found.moved / found.bar), None
    earlier.reason = (
        f"{FOUND_LATE}: {candidate.title}'s confirmation pairs ran it {moved} from its own "
        f"baseline (beyond {bar}, {PAIR_SDS:g} sd of a pair's noise) and {candidate.title} no "
        f"further; its own run(s) had shown {was}, no change"
    )
    group_detection(session, earlier, revision)
    _went(detection, revision, found.moved)
    return revision


def _went(detection: Detection, revision: Revision, moved: float) -> None:
    detection.confirmation_reason += (
        f"; {revision.title}'s runs in these pairs were already at the new level "
        f"({100 * moved:+.1f} % on its own baseline): the change is {revision.title}'s, re-run "
        "against its own baseline"
    )


def still_moved(
    session: Session, revision_id: int, fresh: Iterable[tuple[int, str, str]]
) -> dict[tuple[int, str], int]:
    """Of the revision's verdicts found late (moved back to it, or a level held after it:
    `FOUND_LATER`), those that storing its ``fresh`` verdicts
    ((series id, method, verdict) each) keeps, by (series id, method): those it judges "no
    change" again on its own executions, which missed the change. The fresh verdicts of those
    series and methods are not stored."""
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
        for series_id, method, verdict in fresh
        if (series_id, method) in moved and verdict == NO_CHANGE
    }
