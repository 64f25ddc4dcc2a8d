"""Ingestion and detection on real Postgres, over real MCAP files written by RecordingWriter."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from redline.recording.format import NO_TRAFFIC, SeriesKey
from redline.server.models import Detection, Execution, Job, JobState, Revision, Series, Summary
from redline.server.schemas.components import ComponentCreate
from redline.server.services.components import create_component
from redline.server.services.ingestion import SERIES_PER_INSERT, series_ids
from redline.server.services.revisions import list_revisions
from redline.server.storage import samples_path
from redline.worker.detection import detect_revision
from redline.worker.ingest import ingest_execution
from redline.worker.onward import judge_onward
from sqlalchemy import func, select
from sqlalchemy.exc import DataError

from tests.support.history import add_execution, add_executions, ingest_and_detect
from tests.support.recordings import write_recording


def _history(session, tmp_path: Path, factors: list[float], seed: int = 1) -> list[Execution]:
    """Revisions r1.. of 'builder' whose cpu scales by ``factors``; rss stays put throughout."""
    create_component(session, ComponentCreate(name="builder"))
    rng = np.random.default_rng(seed)
    executions = []
    for number, factor in enumerate(factors, start=1):
        counters = {"cpu": factor * rng.normal(20.0, 2.0, 200), "rss": rng.normal(50e6, 1e5, 200)}
        executions.append(
            add_execution(session, tmp_path, "builder", f"r{number}", str(number), counters)
        )
    return executions


def test_ingest_writes_summaries_parquet_and_marks_the_job_done(session, database_url, tmp_path):
    (execution,) = _history(session, tmp_path, [1.0])
    revisions = ingest_execution(database_url, execution.id)
    session.expire_all()
    assert revisions == [execution.revision_id]
    assert session.get(Job, execution.job_id).state == JobState.done
    series = {s.counter: s for s in session.scalars(select(Series))}
    assert set(series) == {"cpu", "rss"}
    assert series["cpu"].params == '{"rate":10}'
    cpu = session.scalar(select(Summary).where(Summary.series_id == series["cpu"].id))
    assert cpu.n == 200
    assert 18.0 < cpu.mean < 22.0 and 1.0 < cpu.std < 3.0
    assert cpu.min <= cpu.p5 <= cpu.p25 <= cpu.p50 <= cpu.p75 <= cpu.p95 <= cpu.max
    table = pq.read_table(samples_path(execution.recording_path)).to_pandas()
    values = table[table.series_id == series["cpu"].id].value.to_numpy()
    assert values.size == 200 and values.mean() == pytest.approx(cpu.mean)


def test_ingest_twice_replaces_rather_than_doubles(session, database_url, tmp_path):
    (execution,) = _history(session, tmp_path, [1.0])
    ingest_execution(database_url, execution.id)
    ingest_execution(database_url, execution.id)
    assert session.scalar(select(func.count()).select_from(Summary)) == 2
    assert session.scalar(select(func.count()).select_from(Series)) == 2


def test_warmup_phase_is_left_out_of_the_summaries(session, database_url, tmp_path):
    create_component(session, ComponentCreate(name="builder"))
    execution = add_execution(
        session,
        tmp_path,
        "builder",
        "r1",
        "1",
        {"cpu": np.full(30, 10.0)},
        warmup={"cpu": np.full(30, 99.0)},
    )
    ingest_execution(database_url, execution.id)
    summary = session.scalar(select(Summary))
    assert (summary.n, summary.max) == (30, 10.0)


def test_damaged_recording_fails_the_job_with_the_reason(session, database_url, tmp_path):
    (execution,) = _history(session, tmp_path, [1.0])
    data = Path(execution.recording_path).read_bytes()
    Path(execution.recording_path).write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="truncated"):
        ingest_execution(database_url, execution.id)
    session.expire_all()
    job = session.get(Job, execution.job_id)
    assert job.state == JobState.failed
    assert "truncated" in job.reason
    assert session.scalar(select(func.count()).select_from(Summary)) == 0


@pytest.mark.parametrize(
    ("process", "counter", "said"),
    [
        ("svc\x00x", "cpu", "its process must not contain '\\x00' at position 3"),
        ("svc", "cpu\x1b[31m", "its counter must not contain '\\x1b' at position 3"),
    ],
)
def test_a_name_with_a_control_character_fails_its_job_naming_it(
    session, database_url, tmp_path, process: str, counter: str, said: str
):
    """An audit's recording named a process with a NUL: Postgres refused the insert with a
    DataError, which left the job "uploaded" (queued again every few minutes, for good: the
    revision pending, the component undeletable). A control character in a name now fails its
    job, naming it; nothing is stored."""
    create_component(session, ComponentCreate(name="builder"))
    execution = add_execution(
        session, tmp_path, "builder", "r1", "1", {counter: np.full(30, 1.0)}, process=process
    )
    with pytest.raises(ValueError, match="must not contain"):
        ingest_execution(database_url, execution.id)
    session.expire_all()
    job = session.get(Job, execution.job_id)
    assert job.state == JobState.failed, job.state
    assert said in job.reason, job.reason
    assert session.scalar(select(func.count()).select_from(Series)) == 0


def test_a_value_postgres_refuses_fails_its_job_saying_so(session, database_url, tmp_path):
    """A recording's run metadata said "no traffic" with a warning holding a NUL: the job's
    reason could not be stored, Postgres's DataError left the job "uploaded" for good (a
    review's find beside an audit's). It fails the job, saying what the database refused."""
    create_component(session, ComponentCreate(name="builder"))

    def record(path: Path, run: dict[str, str], counters: dict, **extra) -> Path:
        run = {**run, "status": NO_TRAFFIC, "warning": "idle\x00"}
        return write_recording(path, run, counters, **extra)

    (execution,) = add_executions(
        session, tmp_path, "builder", "r1", "1", [{"cpu": np.full(30, 1.0)}], record=record
    )
    with pytest.raises(DataError):
        ingest_execution(database_url, execution.id)
    session.expire_all()
    job = session.get(Job, execution.job_id)
    assert job.state == JobState.failed, job.state
    assert job.reason.startswith("ingest failed: the database refused a value the recording "
                                 "holds (") and "\n" not in job.reason, job.reason  # fmt: skip


def _changes(session) -> dict[tuple[str, str], Detection]:
    """KS's decided verdicts (what the trend charts draw), by counter and revision."""
    rows = session.execute(
        select(Detection, Series.counter, Revision.title)
        .join(Series, Series.id == Detection.series_id)
        .join(Revision, Revision.id == Detection.revision_id)
        .where(Detection.method == "ks", Detection.p_value.is_not(None))
    )
    return {(counter, title): change for change, counter, title in rows}


def test_tripled_counter_is_flagged_and_unchanged_one_is_not(session, database_url, tmp_path):
    executions = _history(session, tmp_path, [1.0, 1.0, 3.0])
    for execution in executions:
        ingest_execution(database_url, execution.id)
    for execution in executions:
        detect_revision(database_url, execution.revision_id)
    changes = _changes(session)
    assert ("cpu", "r1") not in changes and ("rss", "r1") not in changes  # no predecessor
    assert not changes[("cpu", "r2")].flagged and not changes[("rss", "r2")].flagged
    tripled = changes[("cpu", "r3")]
    assert tripled.flagged and tripled.method == "ks"
    assert tripled.effect == pytest.approx(2.0, abs=0.15)
    assert tripled.baseline_revision_id == executions[1].revision_id
    assert not changes[("rss", "r3")].flagged


def test_host_wide_counters_are_context_not_judged(session, database_url, tmp_path):
    create_component(session, ComponentCreate(name="builder"))
    rng = np.random.default_rng(3)
    executions = [
        add_execution(
            session,
            tmp_path,
            "builder",
            f"r{n}",
            str(n),
            {"cpu_percent": factor * rng.normal(20.0, 2.0, 200)},
            process="host",
        )
        for n, factor in ((1, 1.0), (2, 3.0))
    ]
    ingest_and_detect(database_url, executions)
    assert session.scalar(select(func.count()).select_from(Summary)) == 2  # still charted
    assert _changes(session) == {}


def test_change_below_the_counters_absolute_floor_is_not_flagged(session, database_url, tmp_path):
    create_component(session, ComponentCreate(name="builder"))
    rng = np.random.default_rng(4)
    # 4 % of a core → 4.6 %: 15 % relative and clear to KS, but under the 1-point CPU floor;
    # the same 15 % of 40 % of a core clears it.
    executions = [
        add_execution(
            session,
            tmp_path,
            "builder",
            f"r{n}",
            str(n),
            {
                "small_cpu_percent": factor * rng.normal(4.0, 0.05, 200),
                "large_cpu_percent": factor * rng.normal(40.0, 0.5, 200),
            },
        )
        for n, factor in ((1, 1.0), (2, 1.15))
    ]
    ingest_and_detect(database_url, executions)
    changes = _changes(session)
    small, large = changes[("small_cpu_percent", "r2")], changes[("large_cpu_percent", "r2")]
    assert small.p_value < 1e-6 and small.effect == pytest.approx(0.15, abs=0.02)
    assert not small.flagged
    assert large.flagged


def test_detect_again_replaces_its_changes(session, database_url, tmp_path):
    executions = _history(session, tmp_path, [1.0, 3.0])
    for execution in executions:
        ingest_execution(database_url, execution.id)
    detect_revision(database_url, executions[1].revision_id)
    detect_revision(database_url, executions[1].revision_id)
    assert len(_changes(session)) == 2


def test_ingesting_an_earlier_revision_late_judges_its_successor_again(
    session, database_url, tmp_path
):
    first, second = _history(session, tmp_path, [1.0, 3.0])
    assert ingest_execution(database_url, second.id) == [second.revision_id]
    assert detect_revision(database_url, second.revision_id) == []  # no baseline with data yet
    assert ingest_execution(database_url, first.id) == [first.revision_id]
    session.expire_all()
    assert session.get_one(Revision, second.revision_id).analyzed_at is None  # pending again
    assert judge_onward(database_url, first.revision_id) == [first.revision_id, second.revision_id]
    assert _changes(session)[("cpu", "r2")].flagged


def test_baseline_follows_sort_key_not_report_order(session, database_url, tmp_path):
    create_component(session, ComponentCreate(name="builder"))
    late = add_execution(session, tmp_path, "builder", "v10", "10", {"cpu": np.full(50, 30.0)})
    early = add_execution(session, tmp_path, "builder", "v9", "9", {"cpu": np.full(50, 10.0)})
    for execution in (late, early):
        ingest_execution(database_url, execution.id)
    (change,) = detect_revision(database_url, late.revision_id)
    assert change.baseline_revision_id == early.revision_id
    assert change.effect == pytest.approx(2.0)
    assert detect_revision(database_url, early.revision_id) == []


def test_revision_is_analyzing_until_detection_has_run(session, database_url, tmp_path):
    (execution,) = _history(session, tmp_path, [1.0])
    ingest_execution(database_url, execution.id)
    session.expire_all()
    assert [r.state for r in list_revisions(session, "builder")] == ["analyzing"]
    detect_revision(database_url, execution.revision_id)
    session.expire_all()
    assert [r.state for r in list_revisions(session, "builder")] == ["done"]


def test_series_beyond_one_statements_parameters_are_all_created(session):
    """20,000 series in one import took 120,000 parameters, over Postgres's 65,535 for a
    statement; the import was answered "database unavailable" (a trial from outside)."""
    component = create_component(session, ComponentCreate(name="wide"))
    count = 2 * SERIES_PER_INSERT + 1_000  # 66,000 parameters in one statement: too many
    keys = [SeriesKey(f"c{n}", "steady", "{}", "wide", "x") for n in range(count)]
    found = series_ids(session, component.id, keys)
    session.commit()
    assert len(set(found.values())) == count
    assert session.scalar(select(func.count()).select_from(Series)) == count
