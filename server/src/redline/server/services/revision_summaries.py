"""What each revision's verdict says in a few words, for the component page's list of revisions
(`revision_verdicts`)."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Collection

from redline.detect.config import CHARTED_METHOD as CHARTED
from redline.detect.confirmation import DROPPED
from redline.detect.counters import SHARE
from redline.detect.result import waits_for_history
from redline.recording.disturbance import BUSY
from redline.recording.driver import CPU_REFS_PER_OP, DRIVER_PROCESS
from redline.server.models import Detection, Revision, Series
from redline.server.services.components import get_component
from redline.server.services.detection_config import component_config
from sqlalchemy import func, select
from sqlalchemy.orm import Session

#: the component's CPU figures, which a headline names when they were not judged
CPU_FIGURES = (CPU_REFS_PER_OP, SHARE)


def _among(busy: bool, cpu: bool) -> str:
    """What the headline adds of the series not judged: the host busy in some, the CPU among
    them."""
    said = [
        part
        for part, found in (("some because the host was busy", busy), ("its CPU among them", cpu))
        if found
    ]
    return f" ({'; '.join(said)})" if said else ""


#: what a revision without a verdict yet is said to have (`revision_verdicts`)
WAITING = "not enough data yet"


def revision_verdicts(
    session: Session, component_name: str, titles: Collection[str] | None = None
) -> dict[str, str]:
    """Per revision title (of every revision, or of ``titles``), what its alarm method said in a
    few words: its changes, no change, or why there is no verdict yet (the baseline it still
    waits for)."""
    component = get_component(session, component_name)
    method = component_config(session, component.id).alarming[0]
    counts: dict[str, dict[str, int]] = defaultdict(dict)
    why: dict[str, str] = {}
    # a change its re-runs or the history dropped is counted apart: the page said 8 changes
    # where `ci wait` and the verdict, which leave it out, said 7 (a trial)
    dropped = Detection.confirmation == DROPPED
    # the charted method's flags are counted too: a trial's revision read "no change in 22
    # series" above rows of KS's "change (increase) +31.6 %", and nothing said why
    query = (
        select(
            Revision.title,
            Detection.method,
            Detection.verdict,
            dropped,
            func.count(),
            func.min(Detection.reason),
            func.bool_or(Detection.reason.contains(BUSY)),
            func.bool_or(Series.counter.in_(CPU_FIGURES) & (Series.process != DRIVER_PROCESS)),
        )
        .join(Revision, Revision.id == Detection.revision_id)
        .join(Series, Series.id == Detection.series_id)
        .where(Revision.component_id == component.id, Detection.method.in_([method, CHARTED]))
        .group_by(Revision.title, Detection.method, Detection.verdict, dropped)
    )
    if titles is not None:
        query = query.where(Revision.title.in_(list(titles)))
    charted: dict[str, int] = defaultdict(int)
    busy: dict[str, bool] = defaultdict(bool)  # a series not judged because the host was busy
    cpu: dict[str, bool] = defaultdict(bool)  # the component's CPU among those not judged
    for name, used, verdict, was_dropped, number, reason, was_busy, of_cpu in session.execute(
        query
    ):
        if used != method:
            charted[name] += number if verdict == "change" else 0
            continue
        key = "dropped" if verdict == "change" and was_dropped else verdict
        counts[name][key] = counts[name].get(key, 0) + number
        if verdict == "not enough data":
            why[name], busy[name] = reason, busy[name] or bool(was_busy)
            cpu[name] = cpu[name] or bool(of_cpu)
    said = {}
    for title, by in counts.items():
        changed, same, unknown = (
            by.get("change", 0),
            by.get("no change", 0),
            by.get("not enough data", 0),
        )
        not_confirmed = f", {by['dropped']} flagged but not confirmed" if by.get("dropped") else ""
        if changed:
            said[title] = f"{method}: {changed} change(s), {same} series unchanged{not_confirmed}"
        elif same or not_confirmed:
            # "the 20 series judged": a trial read "no change in 20 series, 51 not judged" as
            # the revision's verdict, KS flagging its CPU +150 % beside it
            said[title] = (
                f"{method}: no change in {'the ' if unknown else ''}{same} series"
                + (" judged" if unknown else "")
                + not_confirmed
                + (
                    f", {unknown} not judged" + (" yet" if waits_for_history(why[title]) else "")
                    if unknown
                    else ""
                )
                # a trial's revision read "no change in the 4 series judged, 11 not judged"
                # where CI said undecided, the host busy; and another's "no change in the 13
                # series judged" where its CPU, which its change was in, was not judged yet
                + _among(busy[title], bool(unknown) and cpu[title])
            )
        else:
            said[title] = f"{method}: {WAITING}: {why.get(title, '')}"
        if charted.get(title) and method != CHARTED:
            said[title] += f"; {CHARTED}, which charts and does not alarm, flags {charted[title]}"
    return said
