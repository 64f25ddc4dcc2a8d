"""The worker's tasks under database trouble: a passing outage is retried until the work is
done, a lasting one fails the task after a bounded number of attempts, other errors at once."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from kombu.exceptions import OperationalError as BrokerError
from redline.agent import quiet
from redline.worker import tasks
from redline.worker.ingest import Ingested
from sqlalchemy.exc import InterfaceError, OperationalError

TASKS = [(tasks.ingest_execution, "run_ingest"), (tasks.detect_revision, "judge_onward")]


def _failing(times: int, error: Callable[[], Exception]) -> tuple[Callable, list[int]]:
    """The task's work, failing with ``error`` its first ``times`` calls; and the calls made.
    As ingestion, it asks nothing to be judged; as a walk (`judge_onward`), it judges the
    revision alone, telling it."""
    calls: list[int] = []

    def work(_database_url: str, ident: int, *_args: object, told=None, **_kwargs: object):
        calls.append(ident)
        if len(calls) <= times:
            raise error()
        if told is None:
            return Ingested([])
        told(ident)
        return [ident]

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
        assert renders == [(None, 7), 7]  # its alerts scanned as it is judged


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


class _Broker:
    """Queueing the finishing step, failing the first ``times`` sends as a lost broker does."""

    def __init__(self, times: int) -> None:
        self.times, self.sent = times, []

    def delay(self, *args: int) -> None:
        if self.times > 0:
            self.times -= 1
            raise BrokerError("Error 111 connecting to 127.0.0.1:6379. Connection refused.")
        self.sent.append(args)


def test_a_reanalysis_part_is_tried_again_after_an_outage_and_then_queues_the_end(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls: list[tuple[int, int, int]] = []

    def judge_part(_url: str, component_id: int, run: int, index: int) -> bool:
        calls.append((component_id, run, index))
        if len(calls) == 1:
            raise _outage()()
        return True  # the last part: the finishing step is due (again, after a failed send)

    broker = _Broker(times=1)
    monkeypatch.setattr(tasks.reanalysis, "judge_part", judge_part)
    monkeypatch.setattr(tasks.finish_reanalysis, "delay", broker.delay)
    result = tasks.reanalyze_part.apply(args=(3, 9, 1))
    assert result.successful(), result.traceback
    assert calls == [(3, 9, 1)] * 3  # the outage, the failed send, the success
    assert broker.sent == [(3, 9)]


@pytest.mark.parametrize("step", ["reanalyze_part", "finish_reanalysis"])
def test_a_reanalysis_step_whose_tries_run_out_fails_its_run_with_the_error(
    monkeypatch: pytest.MonkeyPatch, step: str
) -> None:
    failed: list[tuple[int, int, str]] = []
    lasting, _ = _failing(1_000, _outage())
    monkeypatch.setattr(tasks.reanalysis, "judge_part", lambda url, c, *_: lasting(url, c))
    monkeypatch.setattr(tasks.reanalysis_finish, "finish", lambda url, c, *_: lasting(url, c))
    monkeypatch.setattr(
        tasks.reanalysis_finish,
        "fail_run",
        lambda _url, component_id, run, exc: failed.append((component_id, run, str(exc))),
    )
    args = (3, 9, 0) if step == "reanalyze_part" else (3, 9)
    result = getattr(tasks, step).apply(args=args)
    assert result.failed() and isinstance(result.result, OperationalError)
    assert [(c, r) for c, r, _ in failed] == [(3, 9)]
    assert "server closed the connection" in failed[0][2]
