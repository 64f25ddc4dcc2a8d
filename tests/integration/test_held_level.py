"""A level the later revisions hold, found at the revision whose own run missed it
(`redline.worker.held_level`), then confirmed or dropped by its own pairs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from redline.detect.execution_shift import HELD_AFTER, ExecutionShift
from redline.server.models import (
    DetectionConfigRow,
    Host,
    Job,
    JobState,
    Regression,
)
from redline.server.schemas.components import ComponentCreate
from redline.server.schemas.jobs import RegisterRequest
from redline.server.services.ci_verdict import ci_verdict
from redline.server.services.components import create_component
from redline.server.services.jobs import lease_job, register_host
from redline.worker.reanalysis import reanalyze_component
from sqlalchemy import select

from tests.integration.test_confirmation_runs import LATE, MIB, NAME, _detection, _run
from tests.support.history import add_executions, ingest_and_detect

#: one execution a revision (the default): r1-r11 around 20 % CPU, 1.5 % apart; r12 on, +10 %
NOISE = np.array([0.6, -1.0, 1.3, -0.2, 0.9, -1.2, 0.3, -0.7, 1.1, -0.4, 0.1])
BEFORE = list(20.0 * (1 + 0.015 * NOISE))
CHANGED = 12
AFTER = [22.0 * (1 + 0.015 * z) for z in (-0.9, 0.5, -0.3, 0.8)]


def _run_at(level: float, seed: int, counter: str) -> dict[str, np.ndarray]:
    """One execution whose median is ``level`` (its samples tightly around it)."""
    return {counter: np.random.default_rng(seed).normal(level, level * 0.002, 40)}


def _history(
    session,
    database_url: str,
    tmp_path: Path,
    leased: bool = True,
    counter: str = "cpu",
    unit: float = 1.0,
) -> Host:
    """r1-r15 measured on perf-1 with pairs on, one execution each (an import's when not
    ``leased``), the levels above in ``unit`` of ``counter``; r12 made the change."""
    host = _component_on_a_host(session)
    levels = [x * unit for x in BEFORE + AFTER]
    _measure(session, database_url, tmp_path, host, levels, 1, leased=leased, counter=counter)
    return host


def _component_on_a_host(session) -> Host:
    """The component, one execution a revision with pairs on, and its host perf-1."""
    component = create_component(session, ComponentCreate(name=NAME, executions=1))
    session.add(DetectionConfigRow(component_id=component.id, config={"confirm_pairs": 2}))
    session.commit()
    return register_host(session, RegisterRequest(name="perf-1"))


def _measure(
    session,
    database_url: str,
    tmp_path: Path,
    host: Host,
    levels: list[float],
    start: int,
    leased: bool = True,
    counter: str = "cpu",
) -> None:
    """Revisions r<start>.. at ``levels``, one execution each, measured on ``host``, judged."""
    for number, level in enumerate(levels, start=start):
        executions = add_executions(
            session,
            tmp_path,
            NAME,
            f"r{number}",
            f"{number:03d}",
            [_run_at(level, number, counter)],
        )
        job = session.get_one(Job, executions[0].job_id)
        job.host_id, job.attempts = host.id, 1 if leased else 0
        session.commit()
        ingest_and_detect(database_url, executions)
    session.expire_all()


def test_the_history_is_what_the_held_level_is_for():
    """What the tests below rest on: r12's one run is within the noise of the 10 revisions
    before it (the default window), and r12-r15 are not, against the 7 before r12 that r15's
    baseline holds."""
    judge = ExecutionShift().confirmed()
    assert not judge.compare(np.array(BEFORE[-10:]), np.array(AFTER[:1])).flagged
    assert judge.held(np.array(BEFORE[-7:]), np.array(AFTER)).flagged


def test_a_level_held_by_the_revisions_after_a_missed_change_is_found_and_confirmed_there(
    session, database_url, tmp_path
):
    """r12's own run was not flagged, nor were r13-r14's; judging r15, the four revisions from r12
    on hold +10 %: r12's verdict becomes a suspected change, its pairs against r11 show it, and
    the regression is r12's. A re-analysis keeps it."""
    _history(session, database_url, tmp_path)
    for number in range(CHANGED + 1, CHANGED + HELD_AFTER):
        assert not _detection(session, f"r{number}").flagged
    found = _detection(session, f"r{CHANGED}")
    assert found.flagged and found.verdict == "change", found.reason
    assert found.reason.startswith(
        f"found later, when r15 was judged: the {HELD_AFTER} revisions from it on hold a new "
        "level (4 values against the 7 before it)"
    ), found.reason
    assert found.baseline_revision.title == "r11"
    assert found.confirmation == "suspected"
    runs = []
    while (job := lease_job(session, "perf-1", 60, 3)) is not None:
        runs.append((job.pair, job.revision.title, job.confirms_revision.title))
        _run(session, database_url, tmp_path, job, 20.0 if job.revision.title == "r11" else 22.0)
    assert runs == [(1, "r11", "r12"), (1, "r12", "r12"), (2, "r11", "r12"), (2, "r12", "r12")]
    found = _detection(session, f"r{CHANGED}")
    assert found.confirmation == "held", found.confirmation_reason
    assert found.confirmation_reason.startswith("confirmed by 2 of 2 pairs")
    regressions = {
        (r.good_revision.title, r.bad_revision.title): r.confirmation
        for r in session.scalars(select(Regression))
    }
    assert regressions == {("r11", "r12"): "confirmed"}
    assert ci_verdict(session, NAME, "r12").regressions == 1
    assert ci_verdict(session, NAME, "r15").regressions == 0
    said = (found.verdict, found.reason, found.confirmation, found.confirmation_reason)
    reanalyze_component(database_url, found.revision.component_id)
    session.expire_all()
    again = _detection(session, f"r{CHANGED}")
    assert (again.verdict, again.reason, again.confirmation, again.confirmation_reason) == said


def test_a_held_level_its_pairs_do_not_show_is_dropped_and_not_moved_back(
    session, database_url, tmp_path
):
    """Pairs that run r11 and r12 alike drop r12's found level, and it goes no further back: r11
    stays unchanged and no pair runs r10 (a memory counter: its pairs run the suite, where a
    flag's dropped change is otherwise looked for at its baseline revision)."""
    _history(session, database_url, tmp_path, counter=LATE, unit=MIB)
    titles = []
    while (job := lease_job(session, "perf-1", 60, 3)) is not None:
        assert not job.sets_alone
        titles.append(job.revision.title)
        _run(session, database_url, tmp_path, job, 22.0 * MIB, counter=LATE)
    assert titles == ["r11", "r12"], titles  # the first pair decided it
    found = _detection(session, f"r{CHANGED}")
    assert found.confirmation == "dropped", found.confirmation_reason
    assert "already at the new level" not in found.confirmation_reason
    assert _detection(session, "r11").verdict == "no change"
    assert not session.scalars(select(Job).where(Job.state == JobState.queued)).all()


def test_imported_results_keep_their_verdicts_no_pair_could_confirm_a_held_level(
    session, database_url, tmp_path
):
    """No agent measured the history (an import): nothing can re-run r12, so its verdict stays
    as its own run judged it, and no job is queued."""
    _history(session, database_url, tmp_path, leased=False)
    assert _detection(session, f"r{CHANGED}").verdict == "no change"
    assert not session.scalars(select(Job).where(Job.pair > 0)).all()


def _spike_dropped(session, database_url, tmp_path) -> Host:
    """r1-r11 around 20 % CPU, r12's one run at 30 % (a busy host's): flagged, and its pairs,
    r11 and r12 alike at 20, drop it."""
    host = _component_on_a_host(session)
    _measure(session, database_url, tmp_path, host, [*BEFORE, 30.0], 1)
    assert _detection(session, "r12").flagged
    while (job := lease_job(session, "perf-1", 60, 3)) is not None:
        _run(session, database_url, tmp_path, job, 20.0)
    assert _detection(session, "r12").confirmation == "dropped"
    return host


def test_a_spike_its_pairs_dropped_is_no_level_for_the_revisions_after_it(
    session, database_url, tmp_path
):
    """The baseline reads on past a dropped flag (`flagged_and_confirmed`), and so does the
    held level's walk, which then holds r12's spike among the values it judges: r13-r16 back
    at 20 % must find no level at r12 or after it, nor flag anything."""
    host = _spike_dropped(session, database_url, tmp_path)
    _measure(session, database_url, tmp_path, host, BEFORE[:HELD_AFTER], CHANGED + 1)
    for number in range(CHANGED + 1, CHANGED + 1 + HELD_AFTER):
        found = _detection(session, f"r{number}")
        assert not found.flagged and found.verdict == "no change", (number, found.reason)
    assert _detection(session, "r12").confirmation == "dropped"
    kept = [r.confirmation for r in session.scalars(select(Regression))]
    assert kept in ([], ["not_confirmed"]), kept  # r12's, with its figures, if any
    assert not session.scalars(select(Job).where(Job.state == JobState.queued)).all()


@pytest.mark.xfail(
    strict=True,
    reason="known limit (2026-12-08): the dropped spike's value stays among the values before "
    "r13, and the spread a held level is judged by takes the residuals' standard deviation when "
    "it is larger than their MAD: 3.2 with the spike, 0.25 without, so z is 1.0 where it would "
    "be 13.2; leaving a dropped flag's own values out of the baselines would find it",
)
def test_a_level_held_after_a_dropped_spike_is_found_where_it_began(
    session, database_url, tmp_path
):
    """r12's spike dropped, r13 on hold +10 %: their runs alone within the noise (r12's spike
    among the values before them), the held level is found at r13, not at the spike."""
    host = _spike_dropped(session, database_url, tmp_path)
    _measure(session, database_url, tmp_path, host, AFTER, CHANGED + 1)
    found = _detection(session, f"r{CHANGED + 1}")
    assert found.flagged and found.reason.startswith("found later"), found.reason
    assert found.baseline_revision.title == "r12"
    assert _detection(session, "r12").confirmation == "dropped"
