"""Queueing confirmation pairs, and queueing them once more when the host was busy in their runs.

A pair is a baseline run and a candidate run, back to back on the host that measured the flagged
revision (`redline.worker.confirm_runs`). A phase measured while other work loaded the host is
left out, as detection leaves it out (`redline.recording.disturbance`; the agent already ran the
execution again at once). When that leaves a suspected change without the pairs it needs, the
pairs it lacks are queued once more, for the parameter sets of those changes only, and not leased
before `quiet_wait` has passed (``REDLINE_QUIET_WAIT_S``, 5 minutes unless set), when the work
that loaded the host may have ended. Without this,
a trial's threefold CPU regression, every pair of which ran beside a test suite on the same host,
stayed "suspected" for good and no alert was sent. Once only: a host that is busy again leaves
the change to the later revisions, saying so.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timedelta

from redline.detect.confirmation import Hold
from redline.detect.counters import is_cumulative, is_held
from redline.server.core.config import get_settings
from redline.server.models import (
    FINISHED,
    Detection,
    Execution,
    Job,
    Revision,
    Series,
    Summary,
    utcnow,
)
from redline.server.services.revisions import CANCELLED
from redline.worker.history import reanalysing
from sqlalchemy import func, select
from sqlalchemy.orm import Session

#: confirmation jobs take execution indices from here up, apart from a revision's own
FIRST_INDEX = 1000
#: the reason's start of a confirmation job cancelled because its revision was judged again
#: against another baseline (a revision arriving late), against which new pairs were queued
SUPERSEDED = "superseded"


def quiet_wait() -> timedelta:
    """How long pairs queued again after a busy host wait before an agent may lease them."""
    return timedelta(seconds=get_settings().quiet_wait_s)


@dataclass(frozen=True)
class Scope:
    """What a confirmation run runs: per test case, the parameter sets (canonical, as series
    name them) with a suspected change, and whether it runs them ``alone`` or the suite as far
    as the last of them (`selection.choose_sets`)."""

    sets: dict[str, list[str]]
    alone: bool
    #: whether a busy phase spoils the runs: not where every suspect is of what the component
    #: holds (`counters.is_held`), which is judged in a busy phase too
    busy_matters: bool = True


def flagged_scope(session: Session, series: Iterable[int]) -> Scope:
    """The parameter sets of ``series``, to run alone where every one of them measures what a
    component does per unit of time or work (CPU, a round trip), which each set's warm-up
    settles; where one measures what it holds (memory, threads, files:
    `counters.is_cumulative`), the suite as far as the last of them, what ran before them in the
    flagged run included (a leak grows over a run: a set run first shows less of it than the
    flagged run did third). What comes after the last flagged set never runs: it would cost
    machine time and confirm nothing. Where every one of them is of what the component holds
    (`counters.is_held`), a busy phase does not matter: the agent need not run it again."""
    sets: dict[str, set[str]] = defaultdict(set)
    alone, held = True, True
    for case, params, process, counter in session.execute(
        select(Series.case, Series.params, Series.process, Series.counter).where(
            Series.id.in_(list(series))
        )
    ):
        sets[case].add(params)
        alone = alone and not is_cumulative(counter)
        held = held and is_held(process, counter)
    return Scope({case: sorted(sets[case]) for case in sorted(sets)}, alone, not held)


def queue_pairs(
    session: Session,
    revision: Revision,
    baseline: int,
    pairs: range,
    host_id: int,
    scope: Scope,
    not_before: datetime | None = None,
) -> int:
    """Queue ``pairs`` (their numbers) of the ``revision`` against its ``baseline`` revision,
    the baseline's run first, pinned to ``host_id``, each running ``scope``; returns the jobs
    queued."""
    labels = list(revision.component.host_labels or [])
    queued = 0
    for pair in pairs:
        for revision_id in (baseline, revision.id):  # baseline first, then the candidate
            index = session.scalar(
                select(func.coalesce(func.max(Job.execution_index) + 1, FIRST_INDEX)).where(
                    Job.revision_id == revision_id, Job.execution_index >= FIRST_INDEX
                )
            )
            session.add(
                Job(
                    revision_id=revision_id,
                    execution_index=index,
                    pair=pair,
                    confirms_revision_id=revision.id,
                    pinned_host_id=host_id,
                    labels=labels,
                    parameter_sets=scope.sets,
                    sets_alone=scope.alone,
                    busy_matters=scope.busy_matters,
                    not_before=not_before,
                )
            )
            session.flush()
            queued += 1
    return queued


def busy_in(session: Session, jobs: list[Job]) -> set[int]:
    """The series of which a confirmation execution of ``jobs`` has a phase measured while the
    host was busy (confirmation runs leave those out)."""
    return set(
        session.scalars(
            select(Summary.series_id)
            .join(Execution, Execution.id == Summary.execution_id)
            .where(Execution.job_id.in_([job.id for job in jobs]), Summary.disturbed)
        )
    )


def queued_again(jobs: Sequence[Job]) -> set[int]:
    """The pairs among ``jobs`` (one baseline's) queued again after a busy host."""
    return {job.pair for job in jobs if job.not_before is not None}


def _queue_again(
    session: Session,
    revision: Revision,
    baseline: int,
    jobs: Sequence[Job],
    busy: Sequence[Detection],
    count: int,
) -> datetime | None:
    """Queue ``count`` more pairs for the ``busy`` detections (suspected changes the host was
    busy in some pair's run of, which the pairs left undecided), once per baseline: the time
    they may start, or None when they were queued again already (or there is nothing to run)."""
    if not busy or not jobs or queued_again(jobs):
        return None
    if any(job.reason == CANCELLED or job.reason.startswith(SUPERSEDED) for job in jobs):
        return None  # CI cancelled the revision, or it is judged against another baseline now
    if reanalysing(session, revision.component_id):
        return None  # a re-analysis queues no machine time for old revisions
    host_id = jobs[0].pinned_host_id
    if host_id is None:
        return None
    start = utcnow() + quiet_wait()
    first = max(job.pair for job in jobs) + 1
    scope = flagged_scope(session, {d.series_id for d in busy})
    # as the first pairs ran: the changes they left undecided for other reasons (a pair that
    # failed) are judged on these too (a busy phase matters here: held series are never busy)
    scope = replace(scope, alone=scope.alone and all(job.sets_alone for job in jobs))
    queue_pairs(session, revision, baseline, range(first, first + count), host_id, scope, start)
    return start


def run_again(
    session: Session,
    revision: Revision,
    baseline: int,
    jobs: list[Job],
    left: list[tuple[Detection, Hold]],
    held: int = 0,
) -> None:
    """The pairs of the changes ``left`` undecided because the host was busy, queued once more
    for a quieter time; where they cannot be, or need not be (the pairs confirmed ``held`` other
    changes of the revision: it is a regression already, and the later revisions decide these
    as they do for any series the pairs leave undecided), what the pairs said stands."""
    if not left:
        return
    if held:
        # a bench_verdicts leak: its memory confirmed by both pairs, one rate of context
        # switches left undecided by a busy spell ran the suite twice more, for nothing the
        # verdict needed: 299 of the history's 861 s of confirmation (2026-12-07)
        for detection, found in left:
            detection.confirmation = found.state
            detection.confirmation_reason = (
                f"{found.reason}; the host was busy in a pair's run of this series, and its pairs "
                f"are not run again: they confirmed {held} other change(s) of this revision"
            )
        return
    count = len({job.pair for job in jobs})  # as many as were first queued
    start = _queue_again(session, revision, baseline, jobs, [d for d, _ in left], count)
    queued = (
        ""
        if start is None
        else (
            "the host was busy in a confirmation pair's run of this series (left out, as detection "
            f"leaves it out): {count} pair(s) queued again, from {start:%Y-%m-%d %H:%M} UTC, when "
            "the work that loaded it may have ended"
        )
    )
    for detection, found in left:
        detection.confirmation = found.state
        detection.confirmation_reason = queued or found.reason


def waiting(jobs: Sequence[Job]) -> str:
    """What the unfinished pairs queued again wait for ("" when none does)."""
    later = [job for job in jobs if job.not_before and job.state not in FINISHED]
    if not later:
        return ""
    start = min(job.not_before for job in later if job.not_before)
    return (
        f"; {len({job.pair for job in later})} pair(s) queued again because the host was busy, "
        f"from {start:%Y-%m-%d %H:%M} UTC"
    )
