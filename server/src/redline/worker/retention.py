"""Retention: raw recordings (MCAP and the Parquet samples beside them) older than the configured
age are deleted; revisions, executions and summaries are kept forever.

Idempotent: an execution already pruned is skipped, a file already gone is fine.
"""

from __future__ import annotations

import logging
from datetime import timedelta
from pathlib import Path

from redline.server.db import session_scope
from redline.server.models import Execution, utcnow
from redline.server.storage import samples_path
from sqlalchemy import select

log = logging.getLogger(__name__)


def raw_files(recording_path: str) -> list[Path]:
    """The recording and its samples table (``x.mcap`` → ``x.samples.parquet``)."""
    return [Path(recording_path), samples_path(recording_path)]


def prune_recordings(database_url: str, days: int, batch: int = 500) -> int:
    """Delete raw files of executions older than ``days``; mark them pruned; return how many."""
    cutoff = utcnow() - timedelta(days=days)
    pruned = 0
    while True:
        with session_scope(database_url) as session:
            executions = list(
                session.scalars(
                    select(Execution)
                    .where(Execution.created < cutoff, Execution.pruned_at.is_(None))
                    .order_by(Execution.id)
                    .limit(batch)
                    .with_for_update(skip_locked=True)
                )
            )
            for execution in executions:
                for path in raw_files(execution.recording_path):
                    path.unlink(missing_ok=True)
                execution.pruned_at = utcnow()
        pruned += len(executions)
        if len(executions) < batch:
            break
    log.info(
        "retention: pruned the raw recordings of %d executions older than %d days", pruned, days
    )
    return pruned


def _register() -> None:
    from redline.server.core.tasks import RETENTION_TASK
    from redline.worker.app import celery_app

    @celery_app.task(name=RETENTION_TASK, acks_late=True)
    def prune_old_recordings() -> int:
        """The periodic retention run (beat schedule: daily)."""
        settings = celery_app.conf.redline_settings
        return prune_recordings(settings.database_url, settings.retention_days)


_register()
