"""The Celery application: Redis broker from ``REDLINE_REDIS_URL``, no result backend.

Run a worker with ``redline worker`` (or ``celery -A redline.worker.app worker``). The task
names are the server's (`redline.server.core.tasks`), which sends them.
"""

from __future__ import annotations

from celery import Celery
from redline.server.core.config import Settings, get_settings
from redline.server.core.tasks import (
    DELIVER_TASK,
    DIGEST_TASK,
    REQUEUE_TASK,
    RETENTION_TASK,
    celery_client,
)


def make_celery(settings: Settings) -> Celery:
    app = celery_client(settings, include=["redline.worker.tasks", "redline.worker.retention"])
    app.conf.update(
        task_acks_late=True,  # a task lost with its worker is redelivered; tasks are idempotent
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
    )
    app.conf.beat_schedule = {
        "retention": {"task": RETENTION_TASK, "schedule": 24 * 3600.0},
        # an upload whose ingestion was never queued (broker down) or got lost is not forgotten
        "requeue-uploads": {"task": REQUEUE_TASK, "schedule": 5 * 60.0},
        # retries come due, and leases of deliveries whose worker died lapse, between scans
        "deliver-alerts": {
            "task": DELIVER_TASK,
            "schedule": max(1.0, min(30.0, settings.alert_retry_s)),
        },
        "send-digests": {"task": DIGEST_TASK, "schedule": 15 * 60.0},
    }
    app.conf.redline_settings = settings
    return app


celery_app = make_celery(get_settings())
app = celery_app  # `celery -A redline.worker.app` looks for `app` or `celery`
