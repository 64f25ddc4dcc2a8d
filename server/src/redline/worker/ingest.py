"""Ingestion: one execution's MCAP recording -> series, summaries (Postgres) and samples (Parquet).

Idempotent: running it again for the same execution replaces what the last run wrote (two runs
for one execution take turns on its job row), so a lost or doubled queue message is harmless:
`stale_uploads` finds the executions whose ingestion never happened, for the periodic re-queue.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from datetime import timedelta

from redline.recording import read_recording
from redline.recording.disturbance import recording_disturbances, threshold
from redline.recording.format import no_traffic_reason
from redline.server.db import session_scope
from redline.server.models import Execution, Job, JobState, Revision, utcnow
from redline.server.services.analysed import unanalysed
from redline.server.services.fresh_runs import mark_waiting, waiting_on
from redline.server.services.ingestion import store_samples
from redline.server.services.reach import in_reach
from sqlalchemy import select
from sqlalchemy.exc import DataError
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)

#: how long a job may stay `uploaded` (stored, not ingested) before its ingestion is queued again
STALE_UPLOAD = timedelta(minutes=10)


def _ingest(session: Session, execution: Execution) -> Job:
    job = session.get_one(Job, execution.job_id, with_for_update=True)  # one run at a time
    recording = read_recording(execution.recording_path, strict=True)
    revision = session.get_one(Revision, execution.revision_id)
    # a run the component took no part in: its samples are kept, but neither summarized (no
    # point on a trend, no baseline) nor judged; detection says "not enough data" and why
    reason = no_traffic_reason(recording.run)
    samples = recording.series_samples()
    # a phase during which the host was busy is charted, not judged (recording.disturbance)
    disturbed = recording_disturbances(samples, threshold())
    store_samples(session, execution, revision.component_id, samples, reason, disturbed)
    job.state, job.reason = JobState.done, reason or ""
    return job


def _fail(database_url: str, execution_id: int, reason: str) -> None:
    with session_scope(database_url) as session:
        execution = session.get(Execution, execution_id)
        if execution is not None:
            job = session.get_one(Job, execution.job_id)
            job.state, job.reason = JobState.failed, reason
            if job.remeasures_job_id is not None:  # the sweep has those that waited judged
                mark_waiting(session, job.revision_id)


@dataclass(frozen=True)
class Ingested:
    """What an ingestion asks detection to judge: ``revisions``, the first to judge onward from
    (`redline.worker.onward`); ``confirmation``: the execution was a confirmation run, whose
    samples are in no baseline (the later revisions read only its revision's verdicts)."""

    revisions: list[int]
    confirmation: bool = False


def ingest_execution(database_url: str, execution_id: int) -> list[int]:
    """`ingest`'s revisions to judge."""
    return ingest(database_url, execution_id).revisions


#: errors a recording's data raises in the reading, whatever the database does: a job meeting
#: one is failed, not left "uploaded" to be queued again every ten minutes for good (a probe's
#: sample without a time did, and its component could no longer be deleted)
CONTENT_ERRORS: tuple[type[Exception], ...] = (
    KeyError,
    TypeError,
    AttributeError,
    IndexError,
    RecursionError,
    ArithmeticError,  # OverflowError: a whole number too large for a float
)


def ingest(database_url: str, execution_id: int) -> Ingested:
    """Ingest one execution in one transaction and mark its job done.

    Says which revisions to judge, the first to judge onward from (`redline.worker.onward`:
    the later revisions its results are a baseline of follow, in order): the execution's own;
    for a confirmation run, the revision it confirms (`redline.worker.confirm_runs`); for a
    fresh run of a baseline the host was busy in, also the revisions that lacked it
    (`redline.worker.remeasure`). Those, and for new results the later revisions in reach, are
    marked as not yet analysed.
    A bad recording (`RecordingError`, or another ValueError from its data, or one of
    `CONTENT_ERRORS`) marks the job failed with the reason and is raised again. Any other
    error (a database or broker outage, storage) is raised leaving the job `uploaded`, for the
    task's retries or the periodic re-queue to ingest it later: a passing outage must not fail
    a good recording.
    """
    try:
        with session_scope(database_url) as session:
            execution = session.get(Execution, execution_id)
            if execution is None:
                log.warning("execution %s no longer exists; nothing to ingest", execution_id)
                return Ingested([])
            job = _ingest(session, execution)
            if job.confirms_revision_id is not None:
                # a confirmation run: the revision it confirms judges its pairs again
                found = Ingested([job.confirms_revision_id], confirmation=True)
                pending = found.revisions
            else:
                revisions = [execution.revision_id]
                if job.remeasures_job_id is not None:  # a fresh run: who waited for it
                    revisions += waiting_on(session, execution.revision_id)
                found = Ingested(list(dict.fromkeys(revisions)))
                pending = [*found.revisions, *in_reach(session, execution.revision_id)]
            unanalysed(session, pending)
            return found
    except ValueError as exc:  # RecordingError is one
        _fail(database_url, execution_id, f"ingest failed: {exc}")
        raise
    except DataError as exc:  # a value of the recording's Postgres refuses, at every retry too
        said = str(exc.orig or exc).splitlines()[0][:200]  # not the statement that follows
        _fail(database_url, execution_id, f"ingest failed: the database refused a value the "
              f"recording holds ({said})")  # fmt: skip
        raise
    except CONTENT_ERRORS as exc:  # the same data fails the same way at every retry
        _fail(
            database_url,
            execution_id,
            f"ingest failed on the recording's data ({type(exc).__name__}: {str(exc)[:200]}); "
            "a fault of Redline's: report it with the recording",
        )
        raise


def stale_uploads(
    session: Session, older_than: timedelta = STALE_UPLOAD, limit: int = 500
) -> list[int]:
    """Executions whose job has been `uploaded` for longer than ``older_than``, oldest first.

    Their ingestion was never queued (broker down at upload) or was lost; ingestion is
    idempotent, so queueing one again that is merely slow costs a repeat, nothing more.
    """
    return list(
        session.scalars(
            select(Execution.id)
            .join(Job, Job.id == Execution.job_id)
            .where(
                Job.state == JobState.uploaded,
                Job.updated < utcnow() - older_than,
                Execution.pruned_at.is_(None),
            )
            .order_by(Job.updated, Execution.id)
            .limit(limit)
        )
    )
