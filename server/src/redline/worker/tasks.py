"""Celery tasks: thin, id-taking, idempotent wrappers around `ingest` and `detection`."""

from __future__ import annotations

import importlib
import logging
from typing import Any

from celery.signals import worker_init
from redline.agent.quiet import analysing
from redline.server.core.config import Settings
from redline.server.core.tasks import (
    DETECT_TASK,
    INGEST_TASK,
    REANALYZE_TASK,
    RENDER_TASK,
    REQUEUE_TASK,
)
from redline.server.db import session_scope
from redline.worker.app import celery_app
from redline.worker.detection import detect_revision as run_detection
from redline.worker.ingest import ingest_execution as run_ingest
from redline.worker.ingest import stale_uploads
from redline.worker.reanalysis import reanalyze_component as run_reanalysis
from redline.worker.trends import render_component_trends, render_revision_trends
from sqlalchemy.exc import InterfaceError, OperationalError

log = logging.getLogger(__name__)
#: a passing database outage is retried (with backoff), never a failed job or a lost revision
RETRY = dict(autoretry_for=(OperationalError, InterfaceError), retry_backoff=True, max_retries=5)


@worker_init.connect
def _preload(**_kwargs: Any) -> None:
    """Import what the tasks load lazily (pandas, through pyarrow) when the worker starts.

    On a machine that also runs an agent, a cold import inside the first task (seconds of CPU)
    would otherwise land in the middle of a measurement.
    """
    importlib.import_module("pandas")


def _settings() -> Settings:
    return celery_app.conf.redline_settings


@celery_app.task(name=INGEST_TASK, acks_late=True, **RETRY)
def ingest_execution(execution_id: int) -> None:
    """Summarize one uploaded execution, then detect changes for its revision (and the next)."""
    with analysing():
        revisions = run_ingest(_settings().database_url, execution_id)
    for revision_id in revisions:
        detect_revision.delay(revision_id)


@celery_app.task(name=DETECT_TASK, acks_late=True, **RETRY)
def detect_revision(revision_id: int) -> None:
    """Compare a revision with its baseline, series by series (KS), replacing earlier results."""
    with analysing():
        changes = run_detection(_settings().database_url, revision_id)
    log.info(
        "revision %s: %d series compared, %d flagged",
        revision_id,
        len(changes),
        sum(change.flagged for change in changes),
    )
    render_trends.delay(revision_id)


@celery_app.task(name=RENDER_TASK, acks_late=True, **RETRY)
def render_trends(revision_id: int) -> None:
    """Render the default trend view of the revision's component into the page cache."""
    with analysing():
        render_revision_trends(_settings().database_url, revision_id)


@celery_app.task(name=REQUEUE_TASK, acks_late=True)
def requeue_stale_uploads() -> int:
    """Queue again the ingestion of executions left `uploaded` (beat schedule: every 5 min)."""
    with session_scope(_settings().database_url) as session:
        executions = stale_uploads(session)
    for execution_id in executions:
        ingest_execution.delay(execution_id)
    if executions:
        log.warning(
            "ingestion queued again for %d executions left uploaded: %s",
            len(executions),
            executions,
        )
    return len(executions)


@celery_app.task(name=REANALYZE_TASK, acks_late=True)
def reanalyze_component(component_id: int) -> None:
    """Detect every revision of the component again (after a configuration change)."""
    with analysing():
        run_reanalysis(_settings().database_url, component_id)
        render_component_trends(_settings().database_url, component_id)
