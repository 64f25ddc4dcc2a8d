"""A change found a revision late, moved to the revision that made it.

With one execution a revision, a change's own run can miss it (its noise pulled it back under
the threshold); the change then pools into the baseline and is flagged at the next revision,
whose code did not change. That revision's confirmation pairs run it against the changed
revision and rightly show nothing, so the flag is dropped and the change is lost
(`bench_verdicts`: CPU +10 % and +30 % each went so). The same pairs' runs of the baseline
revision do say where the change is (`redline.detect.confirmation.already_moved`): when they sit
beyond the noise of *its* baseline, the flagged way, its verdict of the series becomes a
suspected change, grouped into a regression of its own and confirmed by pairs against its own
baseline revision, as any flagged change is (queued here unless a re-analysis is storing, which
queues no machine time; the pairs queued when the change was first moved are judged then).

The moved verdict outlives the revision's own verdicts being stored again (each of its
confirmation runs has it judged again, on its own executions, which did not show the change):
`still_moved` keeps it, except in a re-analysis, whose later revisions' pairs move it again.

Once only: a change moved back is not moved again, or a host that slowed down since the
history was measured would walk every dropped flag back through it, two runs a revision.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from redline.detect.confirmation import PAIR_SDS, already_moved
from redline.detect.result import CHANGE, NO_CHANGE
from redline.server.models import Detection, Revision
from redline.worker.confirmation import baseline_values
from redline.worker.grouping import group_detection
from redline.worker.history import reanalysing
from sqlalchemy import select
from sqlalchemy.orm import Session

#: how the reason of a verdict moved back begins (and the mark that it is not moved again)
FOUND_LATE = "found a revision late"


def move_back(
    session: Session, detection: Detection, candidate: Revision, reruns: Sequence[float]
) -> Revision | None:
    """The baseline revision of ``detection`` (a change of ``candidate`` its pairs dropped) when
    the pairs' runs of it (``reruns``) show the change there: its verdict of the series is then
    a suspected change in a regression, and ``detection``'s reason says where the change went.
    None when they do not, or when it was moved once already or judged a change already."""
    if detection.reason.startswith(FOUND_LATE) or detection.baseline_revision_id is None:
        return None
    earlier = session.scalar(
        select(Detection).where(
            Detection.series_id == detection.series_id,
            Detection.revision_id == detection.baseline_revision_id,
            Detection.method == detection.method,
        )
    )
    if earlier is None or earlier.verdict != NO_CHANGE:
        return None  # a change already (its own confirmation decides), or never judged
    own = baseline_values(session, earlier)
    found = None if own is None else already_moved(reruns, own, detection.direction)
    if found is None:
        return None
    revision = earlier.revision
    was = f"{100 * earlier.effect:+.1f} %" if earlier.effect is not None else "no figure"
    moved, bar = f"{100 * found.moved:+.1f} %", f"{100 * found.bar:+.1f} %"
    earlier.verdict, earlier.flagged, earlier.direction = CHANGE, True, detection.direction
    earlier.effect, earlier.score, earlier.p_value = found.moved, abs(found.moved / found.bar), None
    earlier.reason = (
        f"{FOUND_LATE}: {candidate.title}'s confirmation pairs ran it {moved} from its own "
        f"baseline (beyond {bar}, {PAIR_SDS:g} sd of a pair's noise) and {candidate.title} no "
        f"further; its own run(s) had shown {was}, no change"
    )
    group_detection(session, earlier, revision)
    detection.confirmation_reason += (
        f"; {revision.title}'s runs in these pairs were already at the new level ({moved} on its "
        f"own baseline): the change is {revision.title}'s, re-run against its own baseline"
    )
    return revision


def still_moved(
    session: Session, revision: Revision, rows: list[dict[str, Any]]
) -> tuple[list[dict[str, Any]], list[int]]:
    """``rows``, the revision's fresh verdicts, less those a change moved back to it stands in
    for (a fresh "no change" of its series and method), and the ids of those moved verdicts,
    which storing keeps. Nothing is kept in a re-analysis."""
    if reanalysing(session, revision.component_id):
        return rows, []
    moved = {
        (series_id, method): ident
        for ident, series_id, method in session.execute(
            select(Detection.id, Detection.series_id, Detection.method).where(
                Detection.revision_id == revision.id, Detection.reason.startswith(FOUND_LATE)
            )
        )
    }
    if not moved:  # nearly always
        return rows, []
    kept = {
        key
        for row in rows
        if (key := (row["series_id"], row["method"])) in moved and row["verdict"] == NO_CHANGE
    }
    return [r for r in rows if (r["series_id"], r["method"]) not in kept], [moved[k] for k in kept]
