"""The work the API hands to the workers: task names, and a sender that builds its Celery client
only when it first sends (the API process never builds the worker's application).

The tasks themselves live in `redline.worker`; this module is all the server knows of them.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from redline.server.core.config import Settings

if TYPE_CHECKING:
    import redis
    from celery import Celery

log = logging.getLogger(__name__)

INGEST_TASK = "redline.ingest_execution"
DETECT_TASK = "redline.detect_revision"
REANALYZE_TASK = "redline.reanalyze_component"
REANALYZE_PART_TASK = "redline.reanalyze_part"
REANALYZE_FINISH_TASK = "redline.finish_reanalysis"
RETENTION_TASK = "redline.prune_old_recordings"
REQUEUE_TASK = "redline.requeue_stale_uploads"
RENDER_TASK = "redline.render_trends"
SCAN_ALERTS_TASK = "redline.scan_alerts"
RUNTIME_ALERT_TASK = "redline.runtime_alert"
DELIVER_TASK = "redline.deliver_alerts"
DIGEST_TASK = "redline.send_digests"
TRAIN_TASK = "redline.train_model"


#: the kinds of work, each on a queue of its own so that an operator can give each its own
#: workers (`redline worker --queues`, docs/operations.md): ingestion of uploads; detection,
#: re-analysis, alert scans, model training and the housekeeping; trend charts; deliveries
#: (webhooks, mails, commit statuses: a slow receiver waits there, never in front of analysis)
QUEUE_KINDS = ("ingest", "detect", "render", "alerts")
_KIND = {INGEST_TASK: "ingest", RENDER_TASK: "render", DELIVER_TASK: "alerts"}  # else: detect


def queue_of(settings: Settings, kind: str) -> str:
    """The Celery queue of a kind of work: detection keeps the settings' own queue name."""
    if kind not in QUEUE_KINDS:
        raise ValueError(f"no queue kind {kind!r}: {', '.join(QUEUE_KINDS)}")
    return settings.queue if kind == "detect" else f"{settings.queue}.{kind}"


def broker_url(redis_url: str) -> str:
    """kombu spells a Redis unix socket ``redis+socket:///path``; we accept ``unix:///path``."""
    if redis_url.startswith("unix://"):
        return "redis+socket://" + redis_url[len("unix://") :]
    return redis_url


def redis_client(settings: Settings) -> redis.Redis:
    """A client of the broker's Redis (a TCP or unix-socket address), failing within 2 s."""
    import redis

    url = broker_url(settings.redis_url)
    if url.startswith("redis+socket://"):
        path = url[len("redis+socket://") :]
        return redis.Redis(unix_socket_path=path, socket_timeout=2, socket_connect_timeout=2)
    return redis.Redis.from_url(url, socket_timeout=2, socket_connect_timeout=2)


def queue_depths(settings: Settings) -> dict[str, int]:
    """Best effort: how many tasks wait in each kind's queue (its Redis list); nothing when
    Redis is away."""
    try:
        with redis_client(settings) as client:
            return {kind: int(client.llen(queue_of(settings, kind))) for kind in QUEUE_KINDS}
    except Exception:
        return {}


def celery_client(settings: Settings, **options: object) -> Celery:
    """A Celery application on the settings' broker and queue (the worker's adds its tasks)."""
    from celery import Celery

    app = Celery("redline", broker=broker_url(settings.redis_url), **options)
    # a running worker looks for tasks whose worker died this often (kombu's default, 10 s x
    # every 10th look, left such a task waiting 100 s past its timeout)
    sweep_s = max(1, min(10, int(settings.task_visibility_s / 4)))
    app.conf.update(
        task_ignore_result=True,
        task_default_queue=settings.queue,
        task_routes={name: {"queue": queue_of(settings, kind)} for name, kind in _KIND.items()},
        broker_connection_retry_on_startup=True,
        broker_transport_options={
            "visibility_timeout": settings.task_visibility_s,
            "unacked_restore_interval": sweep_s,
            "unacked_restore_throttle": 1,
            # a sweep holds a lock for milliseconds; a worker killed holding it stopped every
            # other worker's sweeps until it expired (kombu's default: 300 s)
            "unacked_mutex_expire": 2 * sweep_s,
            # the bookkeeping of taken tasks is the queue's own: a stack sharing the Redis
            # with another (and another visibility timeout) never puts back the other's tasks
            **{
                f"unacked_{key}": f"{settings.queue}.unacked{suffix}"
                for key, suffix in (("key", ""), ("index_key", "_index"), ("mutex_key", "_mutex"))
            },
        },
        task_publish_retry_policy={
            "max_retries": 3,
            "interval_start": 0.2,
            "interval_step": 0.5,
            "interval_max": 1.0,
        },
    )
    return app


class TaskSender:
    """How the API hands work to the workers; a broker outage is logged, never a lost upload."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self._celery: Celery | None = None

    def send(self, name: str, *args: int | None) -> bool:
        try:
            if self._celery is None:
                self._celery = celery_client(self.settings)
            self._celery.send_task(name, args=list(args))
        except Exception:  # the upload is stored; the periodic re-queue (or a repeat) queues it
            log.exception("could not queue %s%r", name, args)
            return False
        return True

    def ingest(self, execution_id: int) -> bool:
        return self.send(INGEST_TASK, execution_id)

    def detect(self, revision_id: int, *also: int) -> bool:
        """Judge the revision, then those after it its results reach, and ``also``."""
        return self.send(DETECT_TASK, revision_id, *also)

    def reanalyze(self, component_id: int) -> bool:
        return self.send(REANALYZE_TASK, component_id)

    def revision_ended(self, revision_id: int) -> bool:
        """Its jobs ended without a judgement to follow (they failed): post its verdict."""
        return self.send(SCAN_ALERTS_TASK, None, revision_id)

    def train(self, model_id: int) -> bool:
        return self.send(TRAIN_TASK, model_id)

    def runtime_alert(self, alarm_id: int) -> bool:
        return self.send(RUNTIME_ALERT_TASK, alarm_id)
