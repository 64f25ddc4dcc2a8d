"""Celery tasks: thin, id-taking, idempotent wrappers around `ingest` and `detection`."""

from __future__ import annotations

import importlib
import logging
from typing import Any

from celery.signals import worker_init
from redline.server.core.config import Settings
from redline.worker.app import DETECT_TASK, INGEST_TASK, celery_app
from redline.worker.detection import detect_revision as run_detection
from redline.worker.ingest import ingest_execution as run_ingest
from redline.worker.reanalysis import REANALYZE_TASK
from redline.worker.reanalysis import reanalyze_component as run_reanalysis

log = logging.getLogger(__name__)


@worker_init.connect
def _preload(**_kwargs: Any) -> None:
    """Import what the tasks load lazily (pandas, through pyarrow) when the worker starts.

    On a machine that also runs an agent, a cold import inside the first task (seconds of CPU)
    would otherwise land in the middle of a measurement.
    """
    importlib.import_module("pandas")


def _settings() -> Settings:
    return celery_app.conf.redline_settings


@celery_app.task(name=INGEST_TASK, acks_late=True)
def ingest_execution(execution_id: int) -> None:
    """Summarize one uploaded execution, then detect changes for its revision (and the next)."""
    revisions = run_ingest(_settings().database_url, execution_id)
    for revision_id in revisions:
        detect_revision.delay(revision_id)


@celery_app.task(name=DETECT_TASK, acks_late=True)
def detect_revision(revision_id: int) -> None:
    """Compare a revision with its baseline, series by series (KS), replacing earlier results."""
    changes = run_detection(_settings().database_url, revision_id)
    log.info("revision %s: %d series compared, %d flagged", revision_id, len(changes),
             sum(change.flagged for change in changes))


@celery_app.task(name=REANALYZE_TASK, acks_late=True)
def reanalyze_component(component_id: int) -> None:
    """Detect every revision of the component again (after a configuration change)."""
    run_reanalysis(_settings().database_url, component_id)
