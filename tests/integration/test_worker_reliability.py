"""The worker under trouble, on real Postgres: passing database outages are retried rather than
failing the job, lost ingestions are queued again, concurrent detections of one revision take
turns, and a revision whose samples were pruned keeps its stored results."""

from __future__ import annotations

import threading
from datetime import timedelta

import pytest
from redline.server.core.tasks import REQUEUE_TASK
from redline.server.models import Detection, Job, JobState, Regression, utcnow
from redline.server.storage import samples_path
from redline.worker import ingest as ingest_module
from redline.worker.app import celery_app
from redline.worker.detection import detect_revision
from redline.worker.ingest import ingest_execution, stale_uploads
from sqlalchemy import func, select, update
from sqlalchemy.exc import OperationalError

from tests.support.history import cpu_history, ingest_and_detect


def _job(session, execution) -> Job:
    session.expire_all()
    return session.get(Job, execution.job_id)


def test_a_passing_database_outage_leaves_the_job_uploaded_for_a_retry(
    session, database_url, tmp_path, monkeypatch
):
    (execution,) = cpu_history(session, tmp_path, [20.0])

    def outage(*_args):
        raise OperationalError("SELECT 1", {}, Exception("server closed the connection"))

    monkeypatch.setattr(ingest_module, "in_reach", outage)
    with pytest.raises(OperationalError):
        ingest_execution(database_url, execution.id)
    job = _job(session, execution)
    assert (job.state, job.reason) == (JobState.uploaded, "")
    monkeypatch.undo()
    assert ingest_execution(database_url, execution.id) == [execution.revision_id]
    assert _job(session, execution).state == JobState.done


def test_an_error_the_data_raises_fails_the_job_instead_of_retrying_it_for_good(
    session, database_url, tmp_path, monkeypatch
):
    """A probe's recording made ingestion raise KeyError: its job stayed "uploaded", queued
    again every ten minutes, and its component could not be deleted."""
    (execution,) = cpu_history(session, tmp_path, [20.0])

    def broken(*_args):
        raise KeyError("t_ns")

    monkeypatch.setattr(ingest_module, "in_reach", broken)
    with pytest.raises(KeyError):
        ingest_execution(database_url, execution.id)
    job = _job(session, execution)
    assert job.state == JobState.failed
    assert job.reason.startswith("ingest failed on the recording's data (KeyError: 't_ns')")


def test_stale_uploads_are_requeued_periodically(session, database_url, tmp_path):
    stuck, fresh, done = cpu_history(session, tmp_path, [20.0, 20.0, 20.0])
    ingest_execution(database_url, done.id)
    old = utcnow() - timedelta(hours=1)
    session.execute(update(Job).where(Job.id.in_([stuck.job_id, done.job_id])).values(updated=old))
    session.commit()
    assert stale_uploads(session) == [stuck.id]
    assert stale_uploads(session, older_than=timedelta(0)) == [stuck.id, fresh.id]
    scheduled = {entry["task"] for entry in celery_app.conf.beat_schedule.values()}
    celery_app.loader.import_default_modules()  # what a worker does as it starts (`include`)
    assert REQUEUE_TASK in scheduled and scheduled <= set(celery_app.tasks)  # all known to it


def _detections(session) -> list[tuple]:
    session.expire_all()
    return sorted(
        session.execute(
            select(
                Detection.series_id,
                Detection.revision_id,
                Detection.method,
                Detection.verdict,
                Detection.score,
                Detection.flagged,
                Detection.baseline_revision_id,
            )
        ).all()
    )


def _counts(session) -> tuple[int, int]:
    return (
        session.scalar(
            select(func.count())
            .select_from(Detection)
            .where(Detection.method == "ks", Detection.p_value.is_not(None))
        ),
        session.scalar(select(func.count()).select_from(Regression)),
    )


def _detect_at_once(
    database_url: str, revision_id: int, barrier: threading.Barrier, errors: list[Exception]
) -> None:
    barrier.wait()
    try:
        detect_revision(database_url, revision_id)
    except Exception as exc:  # noqa: BLE001 - reported by the test's assertion
        errors.append(exc)


def test_concurrent_detections_of_one_revision_both_succeed_as_one_would(
    session, database_url, tmp_path
):
    executions = cpu_history(session, tmp_path, [20.0, 60.0], config={"methods": ["ks"]})
    ingest_and_detect(database_url, executions)
    single, counts = _detections(session), _counts(session)
    revision_id = executions[1].revision_id
    for _ in range(3):
        barrier, errors = threading.Barrier(2), []
        threads = [
            threading.Thread(
                target=_detect_at_once, args=(database_url, revision_id, barrier, errors)
            )
            for _ in range(2)
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert errors == []
        assert _detections(session) == single and _counts(session) == counts


def test_revision_whose_samples_are_pruned_keeps_its_results(session, database_url, tmp_path):
    executions = cpu_history(session, tmp_path, [20.0, 60.0], config={"methods": ["ks"]})
    ingest_and_detect(database_url, executions)
    before, counts = _detections(session), _counts(session)
    assert any(row[5] for row in before) and counts[1] == 1  # r2 flagged, one regression
    for execution in executions:
        samples_path(execution.recording_path).unlink()  # retention
    detect_revision(database_url, executions[1].revision_id)
    assert _detections(session) == before and _counts(session) == counts


def test_a_revision_whose_detection_was_lost_is_judged_by_the_sweep_once_nothing_waits(
    services, session, database_url, tmp_path, monkeypatch
):
    """A review: ingestion clears a revision's analysed mark and queues its detection; a
    detection message lost on its way (the broker away as it was queued) left the revision
    pending for ever, and `ci wait` timed out. The periodic sweep queues it again once its
    component's jobs stood still for `LOST_GRACE`, while no detection or ingestion waits in the
    broker (one waiting may be its own)."""
    import uuid

    from redline.server.core.config import Settings
    from redline.server.core.tasks import queue_depths, queue_of, redis_client
    from redline.server.models import Revision
    from redline.worker import tasks
    from redline.worker.onward import taking_turns
    from redline.worker.sweeps import LOST_GRACE, SWEEP_WITHIN, unjudged_revisions

    judged, lost = cpu_history(session, tmp_path, [20.0, 20.0])
    ingest_and_detect(database_url, [judged])
    ingest_execution(database_url, lost.id)  # its detection message lost
    assert unjudged_revisions(session) == []  # its job moved just now: its message may come
    later = utcnow() + LOST_GRACE + timedelta(minutes=1)
    assert unjudged_revisions(session, now=later) == [[lost.revision_id]]
    with taking_turns(database_url, session.get_one(Revision, lost.revision_id).component_id):
        assert unjudged_revisions(session, now=later) == []  # a walk of it under way
    # nor for ever: a component whose jobs stood still longer than the other sweeps look back
    assert unjudged_revisions(session, now=later + SWEEP_WITHIN) == []
    settings = Settings(database_url=database_url, redis_url=services.redis_url,
                        queue=f"lost-{uuid.uuid4().hex[:8]}")  # fmt: skip
    monkeypatch.setattr(tasks, "_settings", lambda: settings)  # the worker's, as it starts
    old = utcnow() - LOST_GRACE - timedelta(minutes=1)
    session.execute(update(Job).values(updated=old))
    session.commit()
    with redis_client(settings) as client:
        client.rpush(queue_of(settings, "detect"), b"a detection on its way")
        assert queue_depths(settings) == {"ingest": 0, "detect": 1, "render": 0, "alerts": 0}
        assert tasks._lost_detections(session, []) == []  # it may be this revision's
        client.delete(queue_of(settings, "detect"))
    assert tasks._lost_detections(session, [[lost.revision_id]]) == []  # queued already
    assert tasks._lost_detections(session, [], [lost.id]) == []  # its run ingested again
    assert tasks._lost_detections(session, []) == [[lost.revision_id]]
    detect_revision(database_url, lost.revision_id)  # what the task queued does
    session.expire_all()
    assert session.get_one(Revision, lost.revision_id).analyzed_at is not None
    assert unjudged_revisions(session, now=later) == []
