"""A task held by a worker that dies goes back to the queue, on the real Redis broker, even when
the worker died holding the lock under which workers put such tasks back; and a stack sharing
the Redis never puts back the tasks another stack's live worker holds.

Seen in CI: a worker killed mid-task left its task waiting more than 240 s, because kombu's
default expiry of that lock is 300 s: every other worker's sweep found it held and gave up.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from collections.abc import Callable

from celery import Celery
from kombu import Consumer, Message, Queue
from redline.server.core.config import Settings
from redline.server.core.tasks import celery_client

from tests.support.servers import Services

#: the broker's visibility timeout here: a dead worker's task is due back this long after it
#: was taken
VISIBILITY_S = 2
#: ample for the visibility timeout, the lock's expiry and a sweep; kombu's own lock expiry
#: (300 s) is far beyond it
BACK_WITHIN_S = 60.0

#: a worker that takes the one message (never acknowledging it), then takes the lock of the
#: sweeps that put back such messages, and dies of SIGKILL holding both
_DYING_WORKER = """
import os, signal
from celery import Celery
from kombu import Consumer, Message, Queue
from kombu.transport.redis import Mutex
from redline.server.core.config import get_settings
from redline.server.core.tasks import celery_client

settings = get_settings()
with celery_client(settings).connection_for_read() as connection:
    channel, held = connection.default_channel, []
    with Consumer(channel, [Queue(settings.queue)], callbacks=[lambda body, _: held.append(body)]):
        while not held:
            connection.drain_events(timeout=5)
    with channel.conn_or_acquire() as client:
        with Mutex(client, channel.unacked_mutex_key, channel.unacked_mutex_expire):
            os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_task_comes_back_though_its_dead_worker_held_the_lock_of_the_sweeps(
    services: Services,
) -> None:
    settings = _stack(services, "redelivery", VISIBILITY_S)
    app, queue = _published(settings, {"task": "held"})
    env = {
        **os.environ,
        "REDLINE_REDIS_URL": services.redis_url,
        "REDLINE_QUEUE": settings.queue,
        "REDLINE_TASK_VISIBILITY_S": str(VISIBILITY_S),
    }
    dying = subprocess.run([sys.executable, "-c", _DYING_WORKER], env=env, timeout=60)
    assert dying.returncode == -9  # killed holding the message and the lock
    back: list[Message] = []
    _poll(app, queue, back, until=lambda: bool(back), most_s=BACK_WITHIN_S)  # it sweeps
    assert [message.payload for message in back] == [{"task": "held"}], (
        f"the dead worker's message was not back within {BACK_WITHIN_S:.0f} s"
    )
    back[0].ack()


def test_a_stack_sharing_the_redis_never_puts_back_what_another_stacks_worker_holds(
    services: Services,
) -> None:
    patient = _stack(services, "patient", 3600)
    hasty = _stack(services, "hasty", 1)  # its sweeps put back what it took a second ago
    app, queue = _published(patient, {"task": "long"})
    held: list[Message] = []
    with (
        app.connection_for_read() as connection,  # the patient stack's worker takes it
        Consumer(connection.default_channel, [queue], callbacks=[_keep(held)]),
    ):
        while not held:
            connection.drain_events(timeout=5)
        taken: list[Message] = []
        polls = _poll(celery_client(hasty), Queue(hasty.queue), taken, lambda: False, most_s=4.0)
        assert polls >= 3 and not taken
        assert connection.default_channel.client.llen(queue.name) == 0, "put back while held"
        held[0].ack()


def _stack(services: Services, name: str, visibility_s: float) -> Settings:
    """The settings of a stack of its own queue on the tests' Redis."""
    queue = f"{name}-{uuid.uuid4().hex[:8]}"
    return Settings(redis_url=services.redis_url, queue=queue, task_visibility_s=visibility_s)


def _published(settings: Settings, body: dict) -> tuple[Celery, Queue]:
    """The stack's Celery application and queue, ``body`` published on it."""
    app, queue = celery_client(settings), Queue(settings.queue)
    with app.connection_for_write() as connection:
        connection.Producer().publish(body, routing_key=queue.name, declare=[queue])
    return app, queue


def _poll(
    app: Celery,
    queue: Queue,
    into: list[Message],
    until: Callable[[], bool],
    most_s: float,
) -> int:
    """A worker of ``app`` on ``queue`` taking messages ``into`` a list until ``until()`` or
    ``most_s``: how many of its polls found nothing (after each, it may sweep)."""
    idle, began = 0, time.monotonic()
    with (
        app.connection_for_read() as connection,
        Consumer(connection.default_channel, [queue], callbacks=[_keep(into)]),
    ):
        while not until() and time.monotonic() - began < most_s:
            try:
                connection.drain_events(timeout=1)
            except TimeoutError:
                idle += 1
    return idle


def _keep(into: list[Message]) -> Callable[[object, Message], None]:
    """A consumer's callback keeping each message, unacknowledged, ``into`` a list."""
    return lambda _body, message: into.append(message)
