"""Celery tasks: thin, id-taking, idempotent wrappers around `ingest` and `detection`."""

from __future__ import annotations

import importlib
import logging
from collections.abc import Sequence
from typing import Any

from celery import Task
from celery.signals import worker_init
from kombu.exceptions import OperationalError as BrokerError
from redline.agent.quiet import analysing
from redline.server.core.config import Settings
from redline.server.core.tasks import (
    DELIVER_TASK,
    DETECT_TASK,
    DIGEST_TASK,
    INGEST_TASK,
    REANALYZE_FINISH_TASK,
    REANALYZE_PART_TASK,
    REANALYZE_TASK,
    RENDER_TASK,
    REQUEUE_TASK,
    RUNTIME_ALERT_TASK,
    SCAN_ALERTS_TASK,
    TRAIN_TASK,
    queue_depths,
)
from redline.server.db import session_scope
from redline.server.models import Execution, Revision
from redline.worker import reanalysis, reanalysis_finish
from redline.worker.alerts import runtime_alerts
from redline.worker.app import celery_app
from redline.worker.deliver import deliver_due
from redline.worker.digests import send_digests
from redline.worker.follow_ups import tell_component, tell_listened
from redline.worker.ingest import ingest as run_ingest
from redline.worker.ingest import stale_uploads
from redline.worker.onward import judge_onward
from redline.worker.statuses import commit_status
from redline.worker.sweeps import (
    failed_without_status,
    unjudged_after_fresh_runs,
    unjudged_revisions,
    untold_runtime_alarms,
)
from redline.worker.trends import render_component_trends, render_revision_trends
from sqlalchemy import select
from sqlalchemy.exc import InterfaceError, OperationalError
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)
#: a passing database outage is retried (with backoff), never a failed job or a lost revision
RETRY = dict(autoretry_for=(OperationalError, InterfaceError), retry_backoff=True, max_retries=5)
#: a re-analysis's steps also when queueing the next step fails (the broker went away)
RETRY_REANALYSIS = {**RETRY, "autoretry_for": (OperationalError, InterfaceError, BrokerError)}


class ReanalysisStep(Task):
    """A re-analysis's part or finishing step: tried again after a passing outage (each is
    idempotent); when the tries run out its run is failed with the error rather than left
    "running" with no task to end it."""

    def on_failure(
        self, exc: BaseException, task_id: str, args: Any, kwargs: Any, einfo: Any
    ) -> None:
        component_id, run = args[0], args[1]
        reanalysis_finish.fail_run(_settings().database_url, component_id, run, exc)


@worker_init.connect
def _preload(**_kwargs: Any) -> None:
    """Import what the tasks load lazily (pandas, through pyarrow; the detectors' scipy.stats)
    when the worker starts.

    On a machine that also runs an agent, a cold import inside the first task (seconds of CPU)
    would otherwise land in the middle of a measurement. scikit-learn is the exception: only
    the training task needs it, and it imports it holding `analysing` (no run starts then).
    """
    importlib.import_module("pandas")
    importlib.import_module("scipy.stats")


def _settings() -> Settings:
    return celery_app.conf.redline_settings


@celery_app.task(name=INGEST_TASK, acks_late=True, **RETRY)
def ingest_execution(execution_id: int) -> None:
    """Summarize one uploaded execution, then detect changes for its revision and onward."""
    with analysing():
        found = run_ingest(_settings().database_url, execution_id)
    if found.revisions:
        detect_revision.apply_async(
            args=found.revisions, kwargs={"confirmation": found.confirmation}
        )


@celery_app.task(name=DETECT_TASK, acks_late=True, **RETRY)
def detect_revision(revision_id: int, *also: int, confirmation: bool = False) -> None:
    """Compare a revision with its baseline, series by series, replacing earlier results; then
    the later revisions its results are a baseline of, and ``also``, in order
    (`redline.worker.onward`). Each revision's alerts and commit status are queued as soon as
    it is judged."""
    with analysing():
        judged = judge_onward(
            _settings().database_url,
            revision_id,
            also,
            confirmation,
            told=lambda judged_id: scan_alerts.delay(None, judged_id),
        )
    if judged:
        render_trends.delay(judged[-1])


@celery_app.task(name=RENDER_TASK, acks_late=True, **RETRY)
def render_trends(revision_id: int) -> None:
    """Render the default trend view of the revision's component into the page cache."""
    with analysing():
        render_revision_trends(_settings().database_url, revision_id)


@celery_app.task(name=REQUEUE_TASK, acks_late=True)
def requeue_stale_uploads() -> int:
    """Queue again the ingestion of executions left `uploaded` (beat schedule: every 5 min);
    and what a message lost on its way would have left undone: the commit status of revisions
    whose jobs ended failed (which no ingest follows), the judging of revisions that waited
    for a fresh run that ended so or whose detection was lost (`unjudged_revisions`, only
    while no detection or ingestion waits in the broker), the alerts of run-time alarms."""
    with session_scope(_settings().database_url) as session:
        executions = stale_uploads(session)
        revisions = failed_without_status(session)
        unjudged = unjudged_after_fresh_runs(session)
        lost = _lost_detections(session, unjudged, executions)
        alarms = untold_runtime_alarms(session)
    for execution_id in executions:
        ingest_execution.delay(execution_id)
    for revision_id in revisions:
        scan_alerts.delay(None, revision_id)
    for again in unjudged + lost:
        detect_revision.apply_async(args=again)
    if lost:
        log.warning("detection queued again for revisions whose detection was lost: %s", lost)
    for alarm_id in alarms:
        runtime_alert.delay(alarm_id)
    if executions:
        log.warning(
            "ingestion queued again for %d executions left uploaded: %s",
            len(executions),
            executions,
        )
    return len(executions)


def _lost_detections(
    session: Session,
    queued: list[list[int]],
    ingesting: Sequence[int] = (),
) -> list[list[int]]:
    """`unjudged_revisions` without those ``queued`` already and those of the executions
    being ``ingesting`` again, while no detection or ingestion waits in the broker (one
    waiting may be theirs; nothing when it cannot be asked)."""
    depths = queue_depths(_settings())
    if not depths or depths["detect"] or depths["ingest"]:
        return []
    taken = {revision_id for again in queued for revision_id in again}
    if ingesting:
        taken |= set(
            session.scalars(select(Execution.revision_id).where(Execution.id.in_(ingesting)))
        )
    found = ([r for r in ids if r not in taken] for ids in unjudged_revisions(session))
    return [ids for ids in found if ids]


@celery_app.task(name=REANALYZE_TASK, acks_late=True, **RETRY_REANALYSIS)
def reanalyze_component(component_id: int) -> None:
    """Detect every revision of the component again (after a configuration change): planned
    here, judged in parts by series on any worker (`reanalyze_part`), stored in order by the
    finishing step the last part queues (`redline.worker.reanalysis`)."""
    parts = _settings().reanalysis_parts
    run = reanalysis.plan(_settings().database_url, component_id, parts)
    for index in range(parts):
        reanalyze_part.delay(component_id, run, index)


@celery_app.task(name=REANALYZE_PART_TASK, acks_late=True, base=ReanalysisStep, **RETRY_REANALYSIS)
def reanalyze_part(component_id: int, run: int, index: int) -> None:
    """One part's series of every revision judged and staged; the last part queues the end."""
    with analysing():
        last = reanalysis.judge_part(_settings().database_url, component_id, run, index)
    if last:
        finish_reanalysis.delay(component_id, run)


@celery_app.task(
    name=REANALYZE_FINISH_TASK, acks_late=True, base=ReanalysisStep, **RETRY_REANALYSIS
)
def finish_reanalysis(component_id: int, run: int) -> None:
    """The staged verdicts stored in revision order, grouped and confirmed; then the charts and
    the alerts."""
    with analysing():
        if not reanalysis_finish.finish(_settings().database_url, component_id, run):
            return
        render_component_trends(_settings().database_url, component_id)
    scan_alerts.delay(component_id)


@celery_app.task(name=SCAN_ALERTS_TASK, acks_late=True, **RETRY)
def scan_alerts(component_id: int | None, revision_id: int | None = None) -> int:
    """Write the alerts the component's changes call for (`redline.worker.alerts`), and the
    commit status of the revision just judged (whose component it is, when none is given),
    then send."""
    with session_scope(_settings().database_url) as session:
        if component_id is None:
            component_id = session.scalar(
                select(Revision.component_id).where(Revision.id == revision_id)
            )
        if component_id is None:
            return 0  # the revision is gone
        deliveries = tell_component(session, component_id)
        if revision_id is not None:
            deliveries += commit_status(session, revision_id)
    if deliveries:
        deliver_alerts.delay()
    return len(deliveries)


@celery_app.task(name=RUNTIME_ALERT_TASK, acks_late=True, **RETRY)
def runtime_alert(alarm_id: int) -> int:
    """Tell the subscriptions about a fault `redline watch` reported, then send."""
    with session_scope(_settings().database_url) as session:
        deliveries = runtime_alerts(session, alarm_id)
    if deliveries:
        deliver_alerts.delay()
    return len(deliveries)


@celery_app.task(name=DIGEST_TASK, acks_late=True, **RETRY)
def digest_alerts() -> int:
    """The digests whose day has passed (beat schedule), and what else falls due with time
    alone (`tell_listened`: a regression's growth held back a period), then send."""
    with session_scope(_settings().database_url) as session:
        deliveries = send_digests(session)
    deliveries += tell_listened(_settings().database_url)
    if deliveries:
        deliver_alerts.delay()
    return len(deliveries)


@celery_app.task(name=DELIVER_TASK, acks_late=True, **RETRY)
def deliver_alerts() -> dict:
    """Send every due delivery (`redline.worker.deliver`); retries fall due between runs and
    the beat schedule looks for them (`redline.worker.app`)."""
    done = deliver_due(_settings().database_url, _settings())
    return {"sent": done["sent"], "failed": done["failed"]}


@celery_app.task(name=TRAIN_TASK, acks_late=True, **RETRY)
def train_model(model_id: int) -> None:
    """Fit a resource-usage model from the executions its request names."""
    with analysing():  # held before the import too: scikit-learn's takes seconds of CPU
        # imported here, not at the top: scikit-learn took 3 of the 10.7 s a worker's start
        # took on a CI machine (2026-11-28), for a task most workers never run
        from redline.worker.training import train_model as run_training

        run_training(_settings().database_url, _settings().storage_dir, model_id)
