"""Waiting on a test of many processes by their progress, not by the clock, and failing with what
they were doing: the jobs' state and the end of every process's log.

A fixed deadline assumes a quiet machine: the same work takes several times as long while other
tests load it. A wait here gives up only when nothing moved for a while (`STALL_S`), or after a
generous bound in all (`MOST_S`).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest
from redline.server.db import session_factory
from redline.server.models import Detection, Execution, Job, Revision
from redline.server.models import Host as HostRow
from sqlalchemy import func, select

T = TypeVar("T")

#: a wait gives up when nothing it watches moved for this long
STALL_S = 240.0
#: and in any case after this long
MOST_S = 900.0
#: a Celery worker's line about a task: received, succeeded, raised (failed) or retry
_TASK_LINE = re.compile(r"Task (\S+)\[([0-9a-f-]{36})\] (received|succeeded|raised|retry)")


def task_events(log: Path) -> dict[str, str]:
    """Each task's last event in a Celery worker's log (INFO): task id -> received, succeeded,
    raised or retry. A task whose last event is ``received`` was held when the log ended: it is
    acknowledged only after its success is logged (``acks_late``)."""
    text = log.read_text(errors="replace") if log.exists() else ""
    return {task: event for _, task, event in _TASK_LINE.findall(text)}


def tail(log: Path, lines: int = 25) -> str:
    if not log.exists():
        return "(no log)"
    return "\n".join(log.read_text(errors="replace").splitlines()[-lines:])


class Progress:
    """The jobs, executions and verdicts of a test's database, and its processes' logs."""

    def __init__(self, database_url: str, logs: Path) -> None:
        self.database_url, self.logs = database_url, logs
        #: a wait has already reported (a later handler need not print the same again)
        self.reported = False

    def snapshot(self) -> tuple:
        """What moves while the work goes on: each job's state and attempts, the executions,
        the verdicts and the revisions judged."""
        with session_factory(self.database_url)() as session:
            jobs = tuple(session.execute(select(Job.id, Job.state, Job.attempts).order_by(Job.id)))
            counts = tuple(
                session.scalar(query)
                for query in (
                    select(func.count(Execution.id)),
                    select(func.count(Detection.id)),
                    select(func.count()).where(Revision.analyzed_at.is_not(None)),
                )
            )
        return jobs, counts

    def report(self) -> str:
        """The jobs (revision, state, attempts, host, reason) and the end of every log."""
        with session_factory(self.database_url)() as session:
            jobs = session.execute(
                select(Revision.title, Job.id, Job.state, Job.attempts, HostRow.name, Job.reason)
                .join(Revision, Revision.id == Job.revision_id)
                .outerjoin(HostRow, HostRow.id == Job.host_id)
                .order_by(Job.id)
            ).all()
        lines = ["jobs (revision, id, state, attempts, host, reason):"]
        lines += [f"  {tuple(job)}" for job in jobs]
        for log in sorted(self.logs.glob("*.log")):
            lines += [f"--- the end of {log.name}:", tail(log)]
        return "\n".join(lines)

    def until(self, check: Callable[[], T | None], what: str) -> T:
        """``check()`` once it is true; fails, with `report`, when nothing moved for `STALL_S`
        (or after `MOST_S`)."""
        began = moved = time.monotonic()
        seen = self.snapshot()
        while not (found := check()):
            now = time.monotonic()
            if (latest := self.snapshot()) != seen:
                seen, moved = latest, now
            if now - moved > STALL_S or now - began > MOST_S:
                self.reported = True
                pytest.fail(
                    f"gave up waiting: {what} (nothing moved for {now - moved:.0f} s, "
                    f"{now - began:.0f} s in all)\n{self.report()}"
                )
            time.sleep(0.3)
        return found
