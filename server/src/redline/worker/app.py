"""The Celery application: Redis broker from ``REDLINE_REDIS_URL``, no result backend.

Run a worker with ``redline worker`` (or ``celery -A redline.worker.app worker``).
"""

from __future__ import annotations

import logging

from celery import Celery
from redline.server.core.config import Settings, get_settings

log = logging.getLogger(__name__)

INGEST_TASK = "redline.ingest_execution"
DETECT_TASK = "redline.detect_revision"
RETENTION_TASK = "redline.prune_old_recordings"
REQUEUE_TASK = "redline.requeue_stale_uploads"


def broker_url(redis_url: str) -> str:
    """kombu spells a Redis unix socket ``redis+socket:///path``; we accept ``unix:///path``."""
    if redis_url.startswith("unix://"):
        return "redis+socket://" + redis_url[len("unix://") :]
    return redis_url


def make_celery(settings: Settings) -> Celery:
    app = Celery(
        "redline",
        broker=broker_url(settings.redis_url),
        include=["redline.worker.tasks", "redline.worker.retention"],
    )
    app.conf.update(
        task_acks_late=True,  # a task lost with its worker is redelivered; tasks are idempotent
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        task_ignore_result=True,
        task_default_queue=settings.queue,
        broker_connection_retry_on_startup=True,
        task_publish_retry_policy={
            "max_retries": 3,
            "interval_start": 0.2,
            "interval_step": 0.5,
            "interval_max": 1.0,
        },
    )
    app.conf.beat_schedule = {
        "retention": {"task": RETENTION_TASK, "schedule": 24 * 3600.0},
        # an upload whose ingestion was never queued (broker down) or got lost is not forgotten
        "requeue-uploads": {"task": REQUEUE_TASK, "schedule": 5 * 60.0},
    }
    app.conf.redline_settings = settings
    return app


class TaskSender:
    """How the API hands work to the workers; a broker outage is logged, never a lost upload."""

    def __init__(self, settings: Settings) -> None:
        self.celery = make_celery(settings)

    def send(self, name: str, *args: int) -> bool:
        try:
            self.celery.send_task(name, args=list(args))
        except Exception:  # the upload is stored; the periodic re-queue (or a repeat) queues it
            log.exception("could not queue %s%r", name, args)
            return False
        return True

    def ingest(self, execution_id: int) -> bool:
        return self.send(INGEST_TASK, execution_id)

    def detect(self, revision_id: int) -> bool:
        return self.send(DETECT_TASK, revision_id)


celery_app = make_celery(get_settings())
app = celery_app  # `celery -A redline.worker.app` looks for `app` or `celery`
