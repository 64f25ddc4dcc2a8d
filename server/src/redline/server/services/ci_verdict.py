"""A revision's verdict for CI: whether it is settled, and per test case x phase x parameter set
what the alarm methods found; as JSON (`redline ci wait` polls it) and as JUnit XML.

Pending while the revision's own jobs run (a fresh run of it included), until detection has
seen them, while confirmation runs of it are under way, and while its baseline is
run afresh because the host was busy in all its runs (`redline.worker.remeasure`). A change for
the worse that confirmation dropped is not a failure; one still suspected is (the later revisions
may drop it, the CI run cannot wait for them), and says so. A test case left without a verdict
because the host stayed busy, or because its method failed, is "undecided", an error in JUnit:
never a silent pass; so is one the alarm methods cannot judge yet where the charted method sees
a change for the worse of `UNJUDGED_LARGE` or more (after the component's first revision).
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Callable, Sequence
from typing import Any

from redline.detect.config import CHARTED_METHOD
from redline.detect.confirmation import DROPPED
from redline.detect.counters import figure, worse
from redline.detect.result import (
    METHOD_FAILED,
    NOT_ENOUGH_DATA,
    NOT_MEASURED_MARK,
    effect_size,
    waits_for_history,
)
from redline.recording.disturbance import names_busy_host
from redline.recording.driver import DRIVER_PROCESS as DRIVER
from redline.recording.format import NO_TRAFFIC_MARK
from redline.server.models import (
    Detection,
    Execution,
    Revision,
    Series,
    revision_place,
)
from redline.server.schemas.alerts import CaseVerdict, CiVerdict
from redline.server.services.ci_pending import verdict_state
from redline.server.services.components import get_component, get_revision
from redline.server.services.detection_config import component_config
from redline.server.services.host_speed import at_host_speed
from redline.server.services.open_regressions import open_before
from redline.server.services.read import revision_page
from redline.server.services.regression_range import unmeasured_before
from sqlalchemy import select
from sqlalchemy.orm import Session


def _change(detection: Detection, series: Series) -> dict[str, Any]:
    return {
        "process": series.process,
        "counter": series.counter,
        "method": detection.method,
        "effect": detection.effect,
        "p_value": detection.p_value,
        "direction": detection.direction,
        "worse": detection.direction == worse(series.process, series.counter),
        "confirmation": detection.confirmation or "none",
        "confirmation_reason": detection.confirmation_reason,
        "regression": detection.regression_id,
        "detection": detection.id,
    }


def ci_verdict(session: Session, component_name: str, title: str) -> CiVerdict:
    component = get_component(session, component_name)
    revision = get_revision(session, component, title)
    state, said = verdict_state(session, revision)
    groups, charted = _by_case(session, revision, component_config(session, component.id).alarming)
    opening = _first(session, revision)

    def size(detection: Detection, series: Series) -> float:
        """A charted change's size, at the host's speed where it can be had: asked only of
        those the rule for large unjudged changes weighs, as a `ci wait` polls."""
        found = at_host_speed(session, revision, detection, series)
        return detection.effect or 0.0 if found is None else found

    cases = [
        _case_verdict(key, found, charted[key], opening, size) for key, found in groups.items()
    ]
    _name_unmeasured(session, cases)
    regressions = sum(change["worse"] for case in cases for change in case.changes)
    improvements = sum(len(case.changes) for case in cases) - regressions
    skipped = sum(case.state == "skipped" for case in cases)
    undecided = sum(case.state == "undecided" for case in cases)
    before, before_total = open_before(session, revision) if state == "done" else ([], 0)
    return CiVerdict(
        component=component.name,
        revision=revision.title,
        state=state,
        waiting_for=said if state == "pending" else "",
        reason=said if state == "failed" else "",
        regressions=regressions,
        improvements=improvements,
        skipped=skipped,
        undecided=undecided,
        cases=cases,
        page=revision_page(component.name, revision.title),
        open_before=before,
        open_before_total=before_total,
    )


def _name_unmeasured(session: Session, cases: list[CaseVerdict]) -> None:
    """Give each change for the worse the revisions between its baseline and its revision that
    did not measure it (``between``: measured while the host was busy, failed, not run): the
    change may be theirs. A bench run's timeouts, made at r24, were flagged at r25 when the host
    was busy in every run of r24's, and r25's CI job failed for them."""
    worse = [c for case in cases for c in case.changes if c["worse"]]
    if not worse:
        return
    found = unmeasured_before(
        session, [session.get_one(Detection, change["detection"]) for change in worse]
    )
    for change in worse:
        listed = found.get(change["detection"], [])
        named = "; ".join(f"{r.title} ({r.why})" for r in listed[:NAMED])
        if listed:
            more = len(listed) - NAMED
            change["between"] = named + (f"; {more} more" if more > 0 else "")


#: revisions of a range a change for the worse names, at most
NAMED = 3


def _worst_first(change: dict[str, Any]) -> tuple[bool, float]:
    """Changes for the worse first, the largest first (one from zero the largest), as an alert
    names the largest: a trial's JUnit failure led with the round trip where the alert, for the
    same revision, led with the larger CPU change."""
    return not change["worse"], -effect_size(change["effect"])


Found = list[tuple[Detection, Series]]


def _by_case(
    session: Session, revision: Revision, alarming: Sequence[str]
) -> tuple[dict[tuple[str, str, str], Found], dict[tuple[str, str, str], Found]]:
    """The revision's verdicts of the alarm methods, and the charted method's flags for the
    worse, per test case x phase x parameter set."""
    groups: dict[tuple[str, str, str], Found] = defaultdict(list)
    charted: dict[tuple[str, str, str], Found] = defaultdict(list)
    for detection, series in session.execute(
        select(Detection, Series)
        .join(Series, Series.id == Detection.series_id)
        .where(
            Detection.revision_id == revision.id,
            Detection.method.in_([*alarming, CHARTED_METHOD]),
        )
        .order_by(Series.case, Series.phase, Series.params, Series.process, Series.counter)
    ):
        key = (series.case, series.phase, series.params)
        if detection.method in alarming:
            groups[key].append((detection, series))
        elif detection.flagged and detection.direction == worse(series.process, series.counter):
            charted[key].append((detection, series))
    return groups, charted


def _case_verdict(
    key: tuple[str, str, str],
    found: Found,
    seen: Found,
    opening: bool,
    size: Callable[[Detection, Series], float] | None = None,
) -> CaseVerdict:
    """One test case x phase x parameter set: failed, passed, or, where a series that can be
    judged has no verdict yet, skipped or undecided (``seen``: the charted method's flags;
    ``size``: a flag's size for the rule on large unjudged changes, by default its effect)."""
    case, phase, params = key
    changes = sorted(
        (_change(d, s) for d, s in found if d.flagged and d.confirmation != DROPPED),
        key=_worst_first,
    )
    worse_count = sum(c["worse"] for c in changes)
    lacking = [
        (d, s)
        for d, s in found
        if d.verdict == NOT_ENOUGH_DATA and (_undecided(d.reason) or waits_for_history(d.reason))
    ]
    if worse_count or not (lacking or all(d.verdict == NOT_ENOUGH_DATA for d, _ in found)):
        return CaseVerdict(
            case=case,
            phase=phase,
            parameters=json.loads(params),
            state="failed" if worse_count else "passed",
            changes=changes,
        )
    # passed only when every series that can be judged was: a CPU series still short of
    # baseline values beside a judged count of timeouts is no pass (a trial saw 2.5x the CPU
    # pass that way, 2026-11-24)
    busy = [
        (d, s)
        for d, s in lacking
        if _undecided(d.reason) and not (opening and names_busy_host(d.reason))
    ]
    # a component's own counter before the driver's metrics: what a developer changed
    first, series = min(busy or lacking or found, key=lambda f: f[1].process == DRIVER)
    # a figure an alarm method could not judge, in whichever of its series (KS charts the CPU
    # share, the default method judges the CPU per unit of work beside it)
    unjudged = {figure(s.process, s.counter) for _, s in found} - {
        figure(s.process, s.counter) for d, s in found if d.verdict != NOT_ENOUGH_DATA
    }
    large = not opening and any(
        figure(s.process, s.counter) in unjudged
        and UNJUDGED_LARGE <= abs(size(d, s) if size else d.effect or 0.0) < math.inf
        for d, s in seen
    )
    # which verdicts it counts, said (a new user: "(1 of 16 verdicts)" said nothing)
    some = f" for {len(lacking)} of its {len(found)} series" if lacking else ""
    return CaseVerdict(
        case=case,
        phase=phase,
        parameters=json.loads(params),
        state="undecided" if busy or large else "skipped",
        reason=f"not enough data{some}: {series.process} {series.counter}: "
        + (FIRST if opening and not busy else "")
        + first.reason
        + _charted_note(seen)
        + (LARGE_UNJUDGED if large else ""),
        changes=changes,
    )


#: a change for the worse the charted method sees in a test case the alarm methods cannot judge
#: yet that is too large to pass as skipped: undecided instead (a trial's tripled work, +112 to
#: +161 % CPU, passed skipped in 3 of its 4 parameter sets, its baselines too short)
UNJUDGED_LARGE = 0.5
LARGE_UNJUDGED = (
    f": a change of {UNJUDGED_LARGE:.0%} or more is not passed unjudged (undecided until the "
    "alarm methods can judge it)"
)


#: how a case of a component's first measured revision begins its reason: a busy host there
#: spoils no comparison, there being none (a trial's first commit failed CI with exit 4)
FIRST = "the first revision: nothing to compare it with; "


def _first(session: Session, revision: Revision) -> bool:
    """Whether no revision of the component before ``revision`` has results."""
    earlier = (
        select(Execution.id)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(Revision.component_id == revision.component_id, revision_place() < revision.place)
    )
    return not session.scalar(select(earlier.exists()))


def _undecided(reason: str) -> bool:
    """A "not enough data" no wait lifts: the host was busy in every run (and a fresh one), the
    method failed (a trial's threshold of the wrong kind made every verdict fail, and its
    fourfold CPU rise "passed"), a series the revision before measured is gone (a driver
    report missing, an action renamed: a gate that lost a measurement does not pass, as
    `redline compare` does not), or the component took no part in the run (a trial's component
    that answered none of its queries passed with exit 0)."""
    return (
        names_busy_host(reason)
        or reason.startswith(METHOD_FAILED)
        or NOT_MEASURED_MARK in reason
        or NO_TRAFFIC_MARK in reason
    )


def _charted_note(flagged: list[tuple[Detection, Series]]) -> str:
    """What the charted method, which does not alarm, flagged for the worse in a test case the
    alarm methods could not judge yet: a threefold CPU must not pass unmentioned (a trial)."""
    if not flagged:
        return ""
    flagged = sorted(flagged, key=lambda f: -abs(f[0].effect or 0.0))
    said = [
        f"{s.process} {s.counter} {'n/a' if d.effect is None else f'{d.effect * 100:+.0f} %'}"
        for d, s in flagged[:3]
    ]
    more = f" and {len(flagged) - 3} more" if len(flagged) > 3 else ""
    return f"; {CHARTED_METHOD}, which charts but does not alarm, flags {', '.join(said)}{more}"
