"""Confirmation by re-running: a flagged revision and its baseline run again, in interleaved pairs.

What no peer does on its own (Perfherder waits for a person to retrigger; Pinpoint bisects on
request): when a revision's change is flagged and the component asks for ``confirm_pairs``, the
worker queues that many pairs of jobs, the baseline revision's then the candidate's, pinned to
the host that measured the candidate, which leases them in that order (`services.jobs`; a pair
after the first once the pairs before it are judged, so that pairs that decide spare the rest
unrun) and runs the parameter sets with a suspected change: alone, or where a change is in what
the component holds (memory, threads), the suite as far as the last of them. Their
executions are not the revisions' own (they never enter the revisions' verdicts or baselines);
once every pair has run, each suspected change of the candidate is judged on the pairs
(`redline.detect.confirmation.pairs_hold`): "confirmed by k of n pairs", or not confirmed with
the figures. A pair that could not run (the baseline's commit is gone, the host went away and
the lease ran out, the revision was cancelled as superseded) is named in the reason; when no
pair could run, the later revisions confirm the change instead (`redline.worker.confirmation`).
A pair the host was busy in is queued once more, for later (`redline.worker.quiet_pairs`).
Machine time is spent only on flagged revisions, once per revision and baseline (judged again
against a revision that arrived late, its unfinished pairs against the old baseline are
cancelled as superseded and pairs against the new one queued), and only where an agent measured
it (imported results are confirmed by history).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import replace
from datetime import timedelta

from redline.detect.config import DetectionConfig
from redline.detect.confirmation import (
    BY_PAIRS,
    DROPPED,
    HELD,
    LATER_DECIDE,
    SUSPECTED,
    UNDECIDED,
    Hold,
    pairs_decided,
    pairs_hold,
)
from redline.detect.counters import is_count
from redline.server.models import (
    DID_NOT_RUN,
    FINISHED,
    Detection,
    Execution,
    Host,
    Job,
    JobState,
    Revision,
    Series,
    Summary,
    utcnow,
)
from redline.server.services.detection_config import component_config
from redline.server.services.fresh_runs import fresh_run_between
from redline.server.services.jobs import current_pairs
from redline.server.services.revisions import CANCELLED, UNFINISHED
from redline.worker.confirmation import baseline_noise
from redline.worker.cpu_time import REFERENCE_ONLY, in_cpu_time, pair_values
from redline.worker.found_late import move_back, move_back_unjudged
from redline.worker.history import reanalysing
from redline.worker.quiet_pairs import (
    SUPERSEDED,
    busy_in,
    flagged_scope,
    queue_pairs,
    queued_again,
    run_again,
    waiting,
)
from sqlalchemy import exists, select
from sqlalchemy.orm import Session

#: a pinned host silent this long is taken for gone: its confirmation runs fail with the reason
HOST_GONE = timedelta(minutes=30)
#: the reason of a confirmation job cancelled because the pairs before it decided every change
NOT_NEEDED = "not needed: the pairs that ran before it decided every suspected change"


def _suspected(session: Session, revision_id: int) -> list[tuple[Detection, str, str]]:
    return [
        (d, process, counter)
        for d, process, counter in session.execute(
            select(Detection, Series.process, Series.counter)
            .join(Series, Series.id == Detection.series_id)
            .where(Detection.revision_id == revision_id, Detection.confirmation == SUSPECTED)
            .order_by(Detection.id)
        )
    ]


def queue_confirmations(session: Session, revision: Revision, config: DetectionConfig) -> int:
    """Queue the pairs for a revision with suspected changes, once per baseline (judged again
    against a revision that arrived late, its pairs against the old one are superseded);
    returns the jobs queued."""
    if config.confirm_pairs <= 0:
        return 0
    # counts of rare events (timeouts) are confirmed by the later revisions, not by a few
    # pairs (`settle_pairs`): a revision whose only suspects are counts runs nothing again
    suspected = [
        d
        for d, process, counter in _suspected(session, revision.id)
        if d.baseline_revision_id and not is_count(process, counter)
    ]
    if not suspected:
        return 0
    own = select(Job).where(Job.revision_id == revision.id, Job.pair == 0)
    if session.scalar(own.where(Job.state.not_in(FINISHED)).limit(1)) is not None:
        return 0  # its own executions first: a flag on part of them may not stand
    host_id = _measured_on(session, revision)
    if host_id is None:
        return 0  # imported results: no agent measured them, the history confirms them
    if fresh_run_between(session, revision, [d.baseline_revision_id for d in suspected]):
        return 0  # the change may be that revision's: judged again once it ran, then queued
    counts: dict[int, int] = defaultdict(int)
    for detection in suspected:
        counts[detection.baseline_revision_id or 0] += 1
    baseline = max(counts, key=counts.__getitem__)  # the baseline most changes share
    earlier = list(session.scalars(select(Job).where(Job.confirms_revision_id == revision.id)))
    queued_against, current = current_pairs(earlier, revision.id)
    cancelled = any(j.revision_id == revision.id and j.reason == CANCELLED for j in earlier)
    if queued_against == baseline or cancelled:
        return 0  # once per baseline; none for a revision whose runs were cancelled with it
    _supersede(session, revision, current, baseline)
    first = max((job.pair for job in earlier), default=0) + 1
    # what the pairs judge: a series measured against another baseline is left to the history
    scope = flagged_scope(
        session, [d.series_id for d in suspected if d.baseline_revision_id == baseline]
    )
    pairs = range(first, first + config.confirm_pairs)
    return queue_pairs(session, revision, baseline, pairs, host_id, scope)


def _measured_on(session: Session, revision: Revision) -> int | None:
    """The host an agent measured the revision's own executions on (None: imported results,
    whose host no agent serves)."""
    return session.scalar(
        select(Job.host_id)
        .where(
            Job.revision_id == revision.id,
            Job.pair == 0,
            Job.host_id.is_not(None),
            Job.attempts > 0,  # leased by an agent: an import names hosts no agent serves
        )
        .order_by(Job.execution_index)
        .limit(1)
    )


def _supersede(session: Session, revision: Revision, current: list[Job], baseline: int) -> None:
    """Cancel the unfinished runs of pairs queued against another baseline (an agent running
    one gets 409 at its next heartbeat; one already uploaded is kept, in no baseline)."""
    if not current:
        return
    against = session.get_one(Revision, baseline).title
    for job in current:
        if job.state in UNFINISHED:
            job.state, job.lease_expires_at = JobState.cancelled, None
            job.reason = f"{SUPERSEDED}: {revision.title} was judged again against {against}"


def _values(session: Session, jobs: list[Job]) -> dict[tuple[int, int, int], tuple[float, float]]:
    """(series, pair, revision) -> (median, mean) of each confirmation execution that ran, but
    of no phase measured while the host was busy: that pair is then incomplete for the series."""
    rows = session.execute(
        select(Summary.series_id, Job.pair, Job.revision_id, Summary.p50, Summary.mean)
        .join(Execution, Execution.id == Summary.execution_id)
        .join(Job, Job.id == Execution.job_id)
        .where(
            Job.id.in_([job.id for job in jobs]),
            Job.state == JobState.done,
            Summary.disturbed.is_(False),
        )
    )
    return {(s, pair, rid): (p50, mean) for s, pair, rid, p50, mean in rows}


def settle_pairs(session: Session, revision: Revision) -> bool:
    """Judge the revision's suspected changes on its confirmation pairs once they all ran;
    False (nothing settled) when it has none. While they run, the reason says how far."""
    every = list(session.scalars(select(Job).where(Job.confirms_revision_id == revision.id)))
    baseline, jobs = current_pairs(every, revision.id)
    if baseline is None:
        return False
    suspected = _suspected(session, revision.id)
    running = [job for job in jobs if job.state not in FINISHED]
    values = _values(session, jobs)
    noises = {d.id: baseline_noise(session, d) for d, _, _ in suspected}  # one query each
    if running and _decided(revision, jobs, suspected, baseline, values, noises):
        for job in running:  # an agent running one gets 409 at its next heartbeat
            job.state, job.reason, job.lease_expires_at = JobState.cancelled, NOT_NEEDED, None
        running = []
    if running:
        note = waiting(jobs)
        for detection, _, _ in suspected:
            if note and detection.confirmation_reason.startswith(UNDECIDED):
                continue  # what the first pairs said of a change the pairs run again do not judge
            detection.confirmation_reason = (
                f"confirmation runs: {len(jobs) - len(running)} of {len(jobs)} finished{note}"
            )
        return True
    failed = sorted(
        {
            f"{job.revision.title}: {job.reason or job.state.value}"
            for job in jobs
            if job.state in DID_NOT_RUN and job.reason != NOT_NEEDED
        }
    )
    spared = {job.pair for job in jobs if job.reason == NOT_NEEDED}
    pairs = sorted({job.pair for job in jobs} - spared)
    ran = {(job.pair, job.revision_id) for job in jobs if job.state == JobState.done}
    if not any((pair, revision.id) in ran and (pair, baseline) in ran for pair in pairs):
        for detection, _, _ in suspected:  # not one complete pair: the history decides
            detection.confirmation_reason = (
                f"{UNDECIDED}: no confirmation pair could run ({'; '.join(failed)}); {LATER_DECIDE}"
            )
        return True
    again = queued_again(jobs)
    wanted = len(set(pairs) - again)  # the first pairs that ran (a pair run again replaces one)
    busy = busy_in(session, jobs)
    moved: list[Revision] = []
    left: list[tuple[Detection, Hold]] = []  # undecided because the host was busy: run again
    held = 0  # changes the pairs confirmed
    # a change found a revision late is looked for only where the pairs ran the suite as far as
    # the flagged sets, as the revisions' own runs did: alone, a set runs first after the
    # component starts, and its level is not the one its revision's own runs measured (in
    # bench_verdicts, 2026-12-05, the 8-legs set ran 5-11 % above its revision's own run)
    alone = any(job.sets_alone for job in jobs)
    may_judge = rerunnable(session, session.get_one(Revision, baseline))
    may_move = not alone and may_judge
    for detection, process, counter in suspected:
        measured = pair_values(values, detection.series_id, pairs, baseline, revision.id)
        count = is_count(process, counter)
        found = _judged(detection, count, baseline, busy, measured, len(pairs))
        # the pairs judge it: not a count, nor a series measured against another baseline
        judged = not count and detection.baseline_revision_id == baseline
        if found is None:
            found = pairs_hold(
                measured, detection.direction, detection.effect or 0.0, wanted,
                noises[detection.id],
            )  # fmt: skip
            found = in_cpu_time(session, detection, found, values, pairs, revision.id)
            if failed:
                found = replace(found, reason=f"{found.reason} (failed: {'; '.join(failed)})")
        if judged and found.state == SUSPECTED and detection.series_id in busy and not again:
            left.append((detection, found))
            continue
        held += found.state == HELD and found.reason.startswith(BY_PAIRS)
        reason = found.reason
        if spared:
            reason += f"; {len(spared)} more pair(s) not needed: these decided it"
        if again and detection.series_id in busy:
            reason += f"; {len(again - spared)} of them run again after the host was busy"
        detection.confirmation, detection.confirmation_reason = found.state, reason
        # perhaps its baseline revision changed it (not where the reference alone moved)
        if found.state == DROPPED and not reason.startswith(REFERENCE_ONLY):
            earlier = (
                move_back(session, detection, revision, [b for b, _ in measured])
                if may_move
                else None
            ) or (move_back_unjudged(session, detection, revision) if may_judge else None)
            if earlier is not None:
                moved.append(earlier)
    run_again(session, revision, baseline, jobs, left, held)
    for earlier in moved:
        confirm_found_late(session, earlier)
    return True


def _judged(
    detection: Detection,
    count: bool,
    baseline: int,
    busy: set[int],
    measured: list[tuple[float, float]],
    pairs: int,
) -> Hold | None:
    """What the pairs leave undecided before judging their values (`pairs_hold` judges them:
    None): a count of rare events, a series they did not measure against its baseline."""
    if count:
        return Hold(
            SUSPECTED,
            f"{UNDECIDED}: a count of rare events (0 in most runs) is confirmed by the later "
            "revisions, not by a few pairs",
        )
    if detection.baseline_revision_id == baseline and any(
        math.isfinite(b) and math.isfinite(c) for b, c in measured
    ):
        return None
    why = (
        f"the host was busy in every run of the {pairs} pair(s) of this series (their phases "
        "are left out, as detection leaves them out)"
        if detection.baseline_revision_id == baseline and detection.series_id in busy
        else "the pairs did not measure this series against its baseline"
    )
    return Hold(SUSPECTED, f"{UNDECIDED}: {why}; {LATER_DECIDE}")


def rerunnable(session: Session, revision: Revision) -> bool:
    """Whether a change found at the revision late (moved back to it, `redline.worker.found_late`,
    or a held level, `redline.worker.held_level`) can have pairs of its own: its pairs ran
    already, or, where no re-analysis is storing (which queues no machine time), an agent
    measured it."""
    if session.scalar(select(exists().where(Job.confirms_revision_id == revision.id))):
        return True
    return not reanalysing(session, revision.component_id) and (
        _measured_on(session, revision) is not None
    )


def confirm_found_late(session: Session, revision: Revision) -> None:
    """Pairs for a revision a change was found at late (moved back to it,
    `redline.worker.found_late`, or a level the later revisions hold, `redline.worker.held_level`),
    against its own baseline revision, unless a re-analysis is storing (the pairs queued when the
    change was first found are judged then); judged as far as they ran."""
    if not reanalysing(session, revision.component_id):
        queue_confirmations(session, revision, component_config(session, revision.component_id))
    settle_pairs(session, revision)


def _decided(
    revision: Revision,
    jobs: list[Job],
    suspected: list[tuple[Detection, str, str]],
    baseline: int,
    values: dict[tuple[int, int, int], tuple[float, float]],
    noises: dict[int, float],
) -> bool:
    """Whether the pairs complete so far decide every suspected change that the pairs judge,
    whatever the pairs still to run would show (`pairs_decided`): then those need not run."""
    done = {(job.pair, job.revision_id) for job in jobs if job.state == JobState.done}
    gone = {job.pair for job in jobs if job.state in DID_NOT_RUN}
    pairs = sorted({job.pair for job in jobs})
    complete = [p for p in pairs if (p, baseline) in done and (p, revision.id) in done]
    pending = len([p for p in pairs if p not in complete and p not in gone])
    again = queued_again(jobs)  # then as many as were first queued are wanted (`settle_pairs`)
    spared = {job.pair for job in jobs if job.reason == NOT_NEEDED}
    wanted = len(set(pairs) - again - spared) if again else None
    for detection, process, counter in suspected:
        if is_count(process, counter) or detection.baseline_revision_id != baseline:
            continue  # the pairs do not judge it (`settle_pairs`)
        measured = pair_values(values, detection.series_id, complete, baseline, revision.id)
        effect, noise = detection.effect or 0.0, noises[detection.id]
        if not pairs_decided(measured, detection.direction, effect, pending, noise, wanted):
            return False
    return True


def settle_pending_pairs(session: Session, component_id: int) -> None:
    """Fail the confirmation runs whose host has gone, then judge the pairs of every revision of
    the component whose runs have all finished and whose changes still wait for them, whatever
    finished last (an ingested run, a failure, a cancellation): the outcome depends on stored
    data only, as a re-analysis needs."""
    gone = utcnow() - HOST_GONE
    for job, host in session.execute(
        select(Job, Host)
        .join(Host, Host.id == Job.pinned_host_id)
        .join(Revision, Revision.id == Job.revision_id)
        .where(
            Revision.component_id == component_id,
            Job.state.in_((JobState.queued, JobState.leased, JobState.running)),
            Host.last_seen < gone,
        )
    ):
        job.state = JobState.failed
        job.reason = f"its host {host.name} was not seen for {HOST_GONE} (confirmation run)"
    waiting = session.scalars(
        select(Revision)
        .where(
            Revision.component_id == component_id,
            exists().where(Job.confirms_revision_id == Revision.id),
            exists().where(
                Detection.revision_id == Revision.id,
                Detection.confirmation == SUSPECTED,
                ~Detection.confirmation_reason.startswith(UNDECIDED),
            ),
        )
        .order_by(Revision.id)
    )
    for revision in waiting:
        settle_pairs(session, revision)
