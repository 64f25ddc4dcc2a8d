"""The worker's tasks under database trouble: a passing outage is retried until the work is
done, a lasting one fails the task after a bounded number of attempts, other errors at once."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from redline.agent import quiet
from redline.worker import tasks
from sqlalchemy.exc import InterfaceError, OperationalError

TASKS = [(tasks.ingest_execution, "run_ingest"), (tasks.detect_revision, "run_detection")]


def _failing(times: int, error: Callable[[], Exception]) -> tuple[Callable, list[int]]:
    """The task's work, failing with ``error`` its first ``times`` calls; and the calls made."""
    calls: list[int] = []

    def work(_database_url: str, ident: int) -> list[int]:
        calls.append(ident)
        if len(calls) <= times:
            raise error()
        return []  # no further revision to detect

    return work, calls


def _outage(kind: type[OperationalError] = OperationalError) -> Callable[[], Exception]:
    return lambda: kind("SELECT 1", {}, Exception("server closed the connection"))


@pytest.fixture(autouse=True)
def no_measurement_lock(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(quiet.LOCK_VARIABLE, raising=False)


@pytest.fixture(autouse=True)
def renders(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The trend renderings a detection queued (no broker here: the sending is recorded)."""
    queued: list[int] = []
    monkeypatch.setattr(tasks.render_trends, "delay", queued.append)
    monkeypatch.setattr(tasks.scan_alerts, "delay", lambda *args: queued.append(args))
    return queued


@pytest.mark.parametrize("kind", [OperationalError, InterfaceError])
@pytest.mark.parametrize(("task", "work"), TASKS)
def test_a_passing_database_outage_is_retried_until_the_task_succeeds(
    monkeypatch: pytest.MonkeyPatch,
    task,
    work: str,
    kind: type[OperationalError],
    renders: list[int],
) -> None:
    failing, calls = _failing(2, _outage(kind))
    monkeypatch.setattr(tasks, work, failing)
    result = task.apply(args=(7,))
    assert result.successful(), result.traceback
    assert calls == [7, 7, 7]
    if task is tasks.detect_revision:  # once done, its component's trend charts are rendered
        assert renders == [7, (None, 7)]  # and its alerts scanned


@pytest.mark.parametrize(("task", "work"), TASKS)
def test_a_lasting_database_outage_fails_the_task_after_a_bounded_number_of_attempts(
    monkeypatch: pytest.MonkeyPatch, task, work: str
) -> None:
    failing, calls = _failing(1_000, _outage())
    monkeypatch.setattr(tasks, work, failing)
    result = task.apply(args=(7,))
    assert result.failed() and isinstance(result.result, OperationalError)
    assert 2 < len(calls) <= 10, f"{len(calls)} attempts"


@pytest.mark.parametrize(("task", "work"), TASKS)
def test_an_error_that_is_no_outage_fails_the_task_without_a_retry(
    monkeypatch: pytest.MonkeyPatch, task, work: str
) -> None:
    failing, calls = _failing(1_000, lambda: ValueError("truncated recording"))
    monkeypatch.setattr(tasks, work, failing)
    result = task.apply(args=(7,))
    assert result.failed() and isinstance(result.result, ValueError)
    assert calls == [7]
