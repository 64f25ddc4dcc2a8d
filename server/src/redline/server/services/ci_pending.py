"""What a revision's CI verdict waits for (`redline.server.services.ci_verdict`): its own jobs,
a performance host that can take them, detection, confirmation runs of it, a fresh run of its
baseline, or an earlier revision still to be measured; or why it failed."""

from __future__ import annotations

from collections import defaultdict

from redline.detect.confirmation import SUSPECTED
from redline.detect.result import HISTORY_REASONS, NOT_ENOUGH_DATA
from redline.server.models import FINISHED, Detection, Job, JobState, Revision, revision_place
from redline.server.services.fresh_runs import fresh_run_between, fresh_runs_under_way
from redline.server.services.revision_reports import unserved_labels
from redline.server.services.revisions import own_jobs, revision_state
from sqlalchemy import func, or_, select
from sqlalchemy.orm import Session


def _no_host_for(session: Session, queued: list[Job]) -> str:
    """Why no host may ever take the queued jobs, when none can: no host registered, or none
    with every label they need (a trial's jobs for label 'nowhere' said only "waiting for a
    performance host", and `ci wait` timed out saying the same)."""
    missing = unserved_labels(session, {tuple(sorted(job.labels)) for job in queued})
    if missing is None:
        return " (no performance host has registered yet: start one, docs/running-agents.md)"
    if missing:
        return (
            f" (no registered host has the label(s) {', '.join(map(repr, missing))} they "
            "need: give one `redline agent --label` (and its token `--labels`), or change the "
            "component's host_labels)"
        )
    return ""


def verdict_state(session: Session, revision: Revision) -> tuple[str, str]:
    """The verdict's state and, while pending, what it waits for (failed: why)."""
    own = own_jobs(revision)
    state = revision_state([job.state for job in own], analyzed=revision.analyzed_at is not None)
    if state in ("failed", "cancelled"):
        alike: dict[tuple[str, str], list[int]] = defaultdict(list)
        for job in own:
            if job.state in (JobState.failed, JobState.cancelled):
                alike[(job.state.value, job.reason or "no reason given")].append(job.id)
        # one line a reason: a broken suite file failed a trial's 3 executions with one error,
        # said three times
        why = [
            f"{'job' if len(ids) == 1 else 'jobs'} {', '.join(map(str, ids))} {state}"
            + ("" if reason == state else f": {reason}")  # "cancelled: cancelled", a trial read
            for (state, reason), ids in alike.items()
        ]
        return "failed", "; ".join(why)
    if state != "done":
        waits = {
            "empty": "jobs to be created",
            "queued": "a performance host to take its jobs",
            "running": "its jobs to finish",
            "analyzing": "detection to judge its results",
        }
        said = waits.get(state, state)
        earlier = _earlier_unmeasured(session, revision) if state == "analyzing" else None
        if earlier is not None:  # what it waits for in the end: `ci wait` said each by turns
            said = f"an earlier revision, {earlier}, to be measured: its baseline"
        if state == "queued":
            said += _no_host_for(session, [job for job in own if job.state == JobState.queued])
        return "pending", said
    reruns, later = session.execute(
        select(func.count(), func.min(Job.not_before)).where(
            Job.confirms_revision_id == revision.id, Job.state.not_in(FINISHED)
        )
    ).one()
    if reruns:
        again = (
            ", queued again because the host was busy in the first ones (from "
            f"{later:%Y-%m-%d %H:%M} UTC)"
            if later is not None
            else ""
        )
        return "pending", f"confirmation runs of it and its baseline{again}"
    fresh = session.scalar(  # a baseline all of whose runs were disturbed, being run afresh
        fresh_runs_under_way(revision.component_id)
        .where(
            Revision.id.in_(
                select(Detection.baseline_revision_id).where(
                    Detection.revision_id == revision.id, Detection.verdict == NOT_ENOUGH_DATA
                )
            )
        )
        .limit(1)
    )
    if fresh is not None:
        return "pending", f"a fresh run of its baseline {fresh}, whose runs the host was busy in"
    suspected = session.scalars(
        select(Detection.baseline_revision_id).where(
            Detection.revision_id == revision.id, Detection.confirmation == SUSPECTED
        )
    ).all()
    between = fresh_run_between(session, revision, suspected)
    if between is not None:
        return "pending", (
            f"a fresh run of {between}, whose runs the host was busy in: the change flagged "
            "here may be its"
        )
    earlier = _earlier_unmeasured(session, revision)
    if earlier is not None:
        return "pending", f"an earlier revision, {earlier}, to be measured: its baseline"
    return "done", ""


def _earlier_unmeasured(session: Session, revision: Revision) -> str | None:
    """An earlier revision still to run, while this one lacks a baseline: several commits
    reported at once run newest first, and the newest is judged again once they are in."""
    lacking = session.scalar(
        select(Detection.id)
        .where(
            Detection.revision_id == revision.id,
            Detection.verdict == NOT_ENOUGH_DATA,
            or_(*(Detection.reason.startswith(start) for start in HISTORY_REASONS)),
        )
        .limit(1)
    )
    if lacking is None:
        return None
    return session.scalar(
        select(Revision.title)
        .join(Job, Job.revision_id == Revision.id)
        .where(
            Revision.component_id == revision.component_id,
            revision_place() < revision.place,
            Job.pair == 0,
            Job.state.not_in(FINISHED),
        )
        .order_by(Revision.order_key.desc(), Revision.id.desc())
        .limit(1)
    )
