"""Results that arrive late: the later revisions are judged again, in order, as if they had not.

On real Postgres over real recordings (`tests.support.history`): every stored verdict after a
late arrival and its walk must be the one judging the whole history in order gives.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
from redline.server.models import Detection, Execution, Revision, utcnow
from redline.worker import onward
from redline.worker.detection import detect_and_store, detect_revision
from redline.worker.ingest import ingest_execution
from redline.worker.onward import judge_onward
from sqlalchemy import select, update

from tests.support.history import add_execution, cpu_history

#: a noisy level, a step up at r8 (one revision with few samples: r5's arrival moves it)
LEVELS = [20.0, 21.0, 19.0, 20.5, 27.0, 20.0, 19.5, 30.0, 30.5, 29.0, 30.0, 31.0, 30.0, 29.5]


def _verdicts(session) -> list[tuple]:
    session.expire_all()
    return sorted(
        session.execute(
            select(
                Detection.revision_id,
                Detection.series_id,
                Detection.method,
                Detection.verdict,
                Detection.flagged,
                Detection.score,
                Detection.baseline_revision_id,
            )
        ).all()
    )


def _in_order(session, database_url, executions) -> list[tuple]:
    """The verdicts of the same stored data judged revision by revision, oldest first."""
    for execution in executions:
        detect_revision(database_url, execution.revision_id)
    return _verdicts(session)


def _arrive(database_url, executions, late: list[int]) -> None:
    """Each execution ingested and judged onward as it arrives, the ``late`` ones (indexes)
    last."""
    order = [e for i, e in enumerate(executions) if i not in late] + [executions[i] for i in late]
    for execution in order:
        judge_onward(database_url, *_split(ingest_execution(database_url, execution.id)))


def _split(revisions: list[int]) -> tuple[int, list[int]]:
    return revisions[0], revisions[1:]


def test_a_revision_ingested_late_leaves_the_verdicts_judging_in_order_gives(
    session, database_url, tmp_path
):
    executions = cpu_history(session, tmp_path, LEVELS)
    order = [e for i, e in enumerate(executions) if i != 4]
    for execution in order:  # r5 is not there yet
        judge_onward(database_url, *_split(ingest_execution(database_url, execution.id)))
    without = _verdicts(session)
    (late,) = ingest_execution(database_url, executions[4].id)
    told: list[int] = []
    judged = judge_onward(database_url, late, told=told.append)
    assert told == judged  # each revision's alerts as it is judged, not after the walk
    after = _verdicts(session)
    expected = _in_order(session, database_url, executions)
    assert after == expected
    # the walk mattered beyond the next revision: r7's and later verdicts had moved
    revisions = [e.revision_id for e in executions]
    changed_later = {row[0] for row in set(without) - set(expected) if row[0] not in revisions[:6]}
    assert changed_later, "the scenario does not reach past r6: it could not find the defect"
    assert judged == revisions[4:]  # r5 and every later one: all within the window (10)


def test_two_walks_of_a_component_take_turns(session, database_url, tmp_path, monkeypatch):
    """Walks from r3 and r5 at once: the second waits for the first to end, so it reads what
    the first stored (interleaved, each could judge a revision against a neighbour the other
    had not re-judged yet)."""
    executions = cpu_history(session, tmp_path, LEVELS, seed=3)
    _arrive(database_url, executions, late=[])
    expected = _verdicts(session)
    revisions = [e.revision_id for e in executions]
    calls: list[tuple[str, int]] = []
    first_in, go_on = threading.Event(), threading.Event()

    def judged(database_url: str, revision_id: int):
        name = threading.current_thread().name
        calls.append((name, revision_id))
        if name == "from-r3":
            first_in.set()
            assert go_on.wait(30), "the test never let the first walk go on"
        return detect_and_store(database_url, revision_id)

    monkeypatch.setattr(onward, "detect_and_store", judged)
    errors: list[BaseException] = []

    def walk(index: int) -> None:
        try:
            judge_onward(database_url, revisions[index])
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            errors.append(exc)

    first = threading.Thread(target=walk, args=(2,), name="from-r3")
    second = threading.Thread(target=walk, args=(4,), name="from-r5")
    first.start()
    assert first_in.wait(30)
    second.start()
    second.join(1.0)  # time to cut in, were it not held back
    go_on.set()
    first.join()
    second.join()
    assert not errors
    walkers = [name for name, _ in calls]
    assert walkers == sorted(walkers), calls  # every call of the first walk, then the second's
    assert [r for name, r in calls if name == "from-r5"] == revisions[4:]
    assert _verdicts(session) == expected


def test_a_walk_that_changes_nothing_stops_a_window_past_its_revision(
    session, database_url, tmp_path
):
    rng = np.random.default_rng(5)
    executions = cpu_history(session, tmp_path, [rng.normal(20.0, 1.0, 60) for _ in range(30)])
    _arrive(database_url, executions, late=[19])
    revisions = [e.revision_id for e in executions]
    # nothing flagged or undecided moves in a level history: r6 and the 20 after it (twice the
    # window: a baseline may reach past busy revisions, `lookback`), not the 4 more after those
    assert judge_onward(database_url, revisions[5]) == revisions[5:26]
    assert judge_onward(database_url, revisions[29]) == [revisions[29]]
    session.expire_all()
    assert all(revision.analyzed_at is not None for revision in session.scalars(select(Revision)))


@pytest.mark.parametrize("baseline", ["previous", "pinned"])
def test_the_reach_follows_the_baseline(session, database_url, tmp_path, baseline):
    config = (
        {"baseline": baseline, "pinned": "r2"} if baseline == "pinned" else {"baseline": baseline}
    )
    executions = cpu_history(session, tmp_path, [20.0] * 8, config=config)
    _arrive(database_url, executions, late=[])
    revisions = [e.revision_id for e in executions]
    if baseline == "previous":
        assert judge_onward(database_url, revisions[3]) == revisions[3:5]
    else:  # the pinned revision is every later one's baseline; another only the next one's
        assert judge_onward(database_url, revisions[1]) == revisions[1:]
        assert judge_onward(database_url, revisions[3]) == revisions[3:5]


def test_the_next_revision_says_what_a_late_one_measured_that_it_does_not(
    session, database_url, tmp_path
):
    """Even when the late revision is in no baseline (pinned elsewhere), the next one's "not
    measured in this revision" verdicts read it."""
    config = {"baseline": "pinned", "pinned": "r1"}
    executions = cpu_history(session, tmp_path, [20.0] * 3, config=config)
    extra = add_execution(
        session, tmp_path, "builder", "r4", "4", {"cpu": np.full(60, 20.0), "rss": np.full(60, 9.0)}
    )
    late = add_execution(session, tmp_path, "builder", "r5", "5", {"cpu": np.full(60, 20.0)})
    for execution in [*executions, late, extra]:  # r4, which measured rss, comes last
        judge_onward(database_url, *_split(ingest_execution(database_url, execution.id)))
    reasons = {
        reason
        for revision, reason in session.execute(select(Detection.revision_id, Detection.reason))
        if revision == late.revision_id
    }
    assert any("not measured in this revision" in reason for reason in reasons), reasons


def test_a_confirmation_run_walks_on_only_when_its_revision_s_verdicts_moved(
    session, database_url, tmp_path
):
    executions = cpu_history(session, tmp_path, [20.0] * 6)
    _arrive(database_url, executions, late=[])
    revisions = [e.revision_id for e in executions]
    # nothing new for the confirmed revision: its later ones read nothing new either
    assert judge_onward(database_url, revisions[2], confirmation=True) == [revisions[2]]
    session.execute(Detection.__table__.delete().where(Detection.revision_id == revisions[2]))
    session.commit()  # as if its verdicts were other before: they move, the walk goes on
    assert judge_onward(database_url, revisions[2], confirmation=True) == revisions[2:]


def test_a_pruned_revision_is_left_out_of_a_walk_and_never_left_pending(
    session, database_url, tmp_path
):
    executions = cpu_history(session, tmp_path, [20.0] * 5)
    _arrive(database_url, executions[1:], late=[])
    pruned = executions[2]
    session.execute(update(Execution).where(Execution.id == pruned.id).values(pruned_at=utcnow()))
    session.commit()
    (first,) = ingest_execution(database_url, executions[0].id)
    session.expire_all()
    pending = [r.title for r in session.scalars(select(Revision).order_by(Revision.order_key))
               if r.analyzed_at is None]  # fmt: skip
    assert pending == ["r1", "r2", "r4", "r5"]
    revisions = [e.revision_id for e in executions]
    assert judge_onward(database_url, first) == [revisions[0], revisions[1], *revisions[3:]]
    session.expire_all()
    assert all(
        r.analyzed_at is not None
        for r in session.scalars(select(Revision))
        if r.id != pruned.revision_id
    )
