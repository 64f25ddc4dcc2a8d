"""The worker's detection on real Postgres: every configured method per series, baselines,
bad input as stored "not enough data", regressions grouped, re-analysis."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from redline.detect.config import DetectionConfig
from redline.server.models import (
    Component,
    Detection,
    DetectionConfigRow,
    Execution,
    JudgingConfig,
    Reanalysis,
    Regression,
    Revision,
    Series,
    StagedDetection,
    StagedRevision,
    Summary,
)
from redline.server.schemas.components import ComponentCreate
from redline.server.services.components import create_component
from redline.server.services.why import baseline_revisions
from redline.server.storage import samples_path
from redline.worker.detection import detect_revision
from redline.worker.ingest import ingest_execution
from redline.worker.reanalysis import reanalyze_component
from sqlalchemy import delete, func, select

from tests.support.history import COMPONENT as NAME
from tests.support.history import (
    add_execution,
    add_executions,
    cpu_history,
    ingest_and_detect,
    uploaded,
)


def _verdicts(session) -> dict[tuple[str, str], Detection]:
    session.expire_all()
    rows = session.execute(
        select(Detection, Revision.title).join(Revision, Revision.id == Detection.revision_id)
    )
    return {(title, d.method): d for d, title in rows}


def test_default_methods_judge_every_series_and_flag_the_tripled_one(
    session, database_url, tmp_path
):
    # one execution per revision: execution_shift needs 6 earlier ones, r7 has them
    ingest_and_detect(database_url, cpu_history(session, tmp_path, [20.0] * 7 + [60.0]))
    found = _verdicts(session)
    assert {method for _, method in found} == set(DetectionConfig().methods)
    assert DetectionConfig().methods == ("execution_shift", "ks")
    for method in DetectionConfig().methods:
        assert found[("r8", method)].flagged and found[("r8", method)].direction == "increase"
        assert found[("r8", method)].verdict == "change"
        assert not found[("r7", method)].flagged
        assert found[("r7", method)].verdict == "no change"
    assert found[("r8", "ks")].p_value < 1e-6 and found[("r8", "ks")].effect > 1.5
    assert found[("r8", "execution_shift")].baseline_revisions == 7
    assert found[("r6", "execution_shift")].verdict == "not enough data"
    assert "baseline has 5, needs 6" in found[("r6", "execution_shift")].reason
    (regression,) = session.scalars(select(Regression))
    assert regression.state == "new"
    # execution_shift's flag raises it; KS's is stored and charted, not an alarm by default
    assert found[("r8", "execution_shift")].regression_id == regression.id
    assert found[("r8", "ks")].regression_id is None


def _runs_history(
    session, tmp_path: Path, levels: list[float], runs: int = 3, config: dict | None = None
) -> list[Execution]:
    """Revisions of ``runs`` executions each; every execution's 'cpu' has its own level (3 %
    run-to-run noise around the revision's) and 40 samples."""
    component = create_component(session, ComponentCreate(name=NAME, executions=runs))
    if config is not None:
        session.add(DetectionConfigRow(component_id=component.id, config=config))
        session.commit()
    rng = np.random.default_rng(4)
    executions = []
    for number, level in enumerate(levels, start=1):
        counters = [
            {"cpu": rng.normal(level * (1 + rng.normal(0, 0.03)), level * 0.1, 40)}
            for _ in range(runs)
        ]
        executions += add_executions(session, tmp_path, NAME, f"r{number}", str(number), counters)
    return executions


def test_execution_shift_judges_executions_and_restarts_its_baseline_after_a_change(
    session, database_url, tmp_path
):
    executions = _runs_history(
        session, tmp_path, [15.0] * 6 + [19.5] * 4, config={"methods": ["execution_shift"]}
    )
    ingest_and_detect(database_url, executions)
    found = {title: d for (title, _), d in _verdicts(session).items()}
    assert "too few samples: baseline has 3, needs 6" in found["r2"].reason
    assert [t for t, d in sorted(found.items(), key=lambda i: int(i[0][1:])) if d.flagged] == ["r7"]
    assert found["r6"].baseline_revisions == 5  # 15 execution values: r1..r5
    r7 = found["r7"].revision_id
    # after the change the baseline restarts at r7: r8 is judged against the new level only
    assert (found["r8"].baseline_revisions, found["r8"].baseline_revision_id) == (1, r7)
    assert found["r8"].verdict == "not enough data"  # r7's 3 values are fewer than 6
    assert found["r9"].baseline_revisions == 2 and found["r9"].verdict == "no change"
    assert 0.2 < found["r7"].effect < 0.4


@pytest.mark.parametrize("parts", [1, 3])
def test_reanalysis_reproduces_the_verdicts_of_detection_revision_by_revision(
    session, database_url, tmp_path, parts
):
    executions = _runs_history(session, tmp_path, [15.0] * 5 + [19.5] * 3 + [15.0] * 3)
    ingest_and_detect(database_url, executions)

    def keyed():
        return {
            key: (d.verdict, d.score, d.baseline_revisions, d.baseline_revision_id)
            for key, d in _verdicts(session).items()
        }

    def grouped():
        session.expire_all()
        return sorted(
            (r.good_revision_id, r.bad_revision_id, r.confirmation, r.confirmation_reason)
            for r in session.scalars(select(Regression))
        )

    incremental, regressions = keyed(), grouped()
    assert any(d[0] == "change" for d in incremental.values()) and regressions
    component = session.scalar(select(Component))
    assert reanalyze_component(database_url, component.id, parts) == 11
    assert keyed() == incremental and grouped() == regressions
    assert session.scalar(select(func.count()).select_from(StagedDetection)) == 0  # cleared


def _blind_window_history(session, database_url, tmp_path) -> None:
    """One execution a revision (an import, a team sparing machine time): r1-r3 at 10 %, then
    r4-r12 at 20 %. When r4 was measured its baseline held 3 values of the 6 needed."""
    ingest_and_detect(database_url, cpu_history(session, tmp_path, [10.0] * 3 + [20.0] * 9))


def test_a_change_in_a_history_too_short_to_judge_is_found_at_its_revision_later(
    session, database_url, tmp_path
):
    """A change landing where the history was too short to judge it is neither lost in the
    baselines that pool it nor pinned on a later, innocent revision: once the revisions after
    it measured the new level, the step is flagged at the revision it came with."""
    _blind_window_history(session, database_url, tmp_path)
    found = {
        title: d for (title, method), d in _verdicts(session).items() if method == "execution_shift"
    }
    assert [t for t, d in sorted(found.items(), key=lambda i: int(i[0][1:])) if d.flagged] == ["r4"]
    r4 = found["r4"]
    assert r4.direction == "increase" and 0.9 < r4.effect < 1.1
    assert r4.baseline_revisions == 3 and "found when r6 was judged" in r4.reason
    # its page shows the bar it was held to, not the confirmed one beside it (a reviewer)
    from redline.server.services.why import why_flagged

    why = why_flagged(session, r4.id)
    assert (why.thresholds["threshold"], why.thresholds_judged) == (10.0, True)
    assert why.bar == "a step found later: judged at 8 × 1.25, and no pair judges it"
    assert why_flagged(session, found["r10"].id).bar == ""
    # the revisions after it are judged against the new level, from r4 on
    assert found["r10"].verdict == "no change" and found["r10"].baseline_revisions == 6
    regression = session.scalars(select(Regression)).one()
    assert (regression.good_revision.title, regression.bad_revision.title) == ("r3", "r4")
    assert regression.confirmation == "confirmed", regression.confirmation_reason


@pytest.mark.parametrize(("parts", "one_batch"), [(1, False), (2, False), (1, True)])
def test_a_reanalysis_finds_the_same_step_at_the_same_revision(
    session, database_url, tmp_path, monkeypatch, parts, one_batch
):
    """``one_batch``: the part's writer stages every revision in one transaction, the step's
    revision (r4) with the one that found it (r6)."""
    from redline.worker import reanalysis

    if one_batch:  # the writer starts only once everything is judged and queued
        start, finish = reanalysis._Stager.start, reanalysis._Stager.finish
        monkeypatch.setattr(reanalysis, "WRITE_AHEAD", 64)
        monkeypatch.setattr(reanalysis._Stager, "start", lambda self: None)
        monkeypatch.setattr(
            reanalysis._Stager, "finish", lambda self: (start(self), finish(self))[1]
        )
    _blind_window_history(session, database_url, tmp_path)
    before = {
        key: (d.verdict, d.score, d.baseline_revision_id) for key, d in _verdicts(session).items()
    }
    regressions = [
        (r.good_revision_id, r.bad_revision_id) for r in session.scalars(select(Regression))
    ]
    component = session.scalar(select(Component))
    assert reanalyze_component(database_url, component.id, parts) == 12
    after = {
        key: (d.verdict, d.score, d.baseline_revision_id) for key, d in _verdicts(session).items()
    }
    assert after == before
    # one verdict a revision, series and method: a step's replaces what was staged of it
    assert session.scalar(select(func.count()).select_from(Detection)) == len(before)
    session.expire_all()
    assert [
        (r.good_revision_id, r.bad_revision_id) for r in session.scalars(select(Regression))
    ] == regressions


def test_first_revision_says_missing_baseline_for_every_method(session, database_url, tmp_path):
    ingest_and_detect(database_url, cpu_history(session, tmp_path, [20.0]))
    found = _verdicts(session)
    assert found and all(
        d.verdict == "not enough data"
        and "missing baseline" in d.reason
        and not d.flagged
        and d.baseline_revision_id is None
        for d in found.values()
    )


@pytest.mark.parametrize(
    ("candidate", "reason"),
    [
        (np.array([25.0]), "too few samples: candidate has 1"),
        (np.full(60, 20.0), "constant series"),
    ],
)
def test_bad_candidate_is_stored_as_not_enough_data_with_what_is_missing(
    session, database_url, tmp_path, candidate, reason
):
    baseline = np.full(60, 20.0) if reason == "constant series" else None
    first = baseline if baseline is not None else 20.0
    ingest_and_detect(database_url, cpu_history(session, tmp_path, [first, candidate]))
    found = _verdicts(session)
    for method in DetectionConfig().methods:
        verdict = found[("r2", method)]
        expected = reason
        if method == "execution_shift":  # one value per execution: r1 gives 1 of the 6 needed
            expected = "too few samples: baseline has 1"
        assert verdict.verdict == "not enough data", (method, verdict.reason)
        assert expected in verdict.reason and not verdict.flagged


def test_baseline_samples_gone_is_missing_baseline_not_an_exception(
    session, database_url, tmp_path
):
    executions = cpu_history(session, tmp_path, [20.0, 60.0])
    for execution in executions:
        ingest_execution(database_url, execution.id)
    samples_path(executions[0].recording_path).unlink()  # pruned
    detect_revision(database_url, executions[1].revision_id)
    verdict = _verdicts(session)[("r2", "ks")]
    assert verdict.verdict == "not enough data" and "missing baseline" in verdict.reason


def test_a_revision_whose_samples_are_gone_keeps_its_verdicts_and_is_not_left_pending(
    session, database_url, tmp_path
):
    """Marked not yet analysed (a fresh run it waited for ended without results, say), a
    revision whose samples were pruned is judged again: its stored verdicts stand, and it is
    analysed again, not pending for ever (its CI verdict would wait for ever)."""
    executions = cpu_history(session, tmp_path, [20.0, 60.0])
    for execution in executions:
        ingest_execution(database_url, execution.id)
        detect_revision(database_url, execution.revision_id)
    before = {key: d.verdict for key, d in _verdicts(session).items()}
    samples_path(executions[1].recording_path).unlink()  # pruned
    revision = session.get_one(Revision, executions[1].revision_id)
    revision.analyzed_at = None
    session.commit()
    assert detect_revision(database_url, revision.id) == []
    session.expire_all()
    assert revision.analyzed_at is not None
    assert {key: d.verdict for key, d in _verdicts(session).items()} == before


def test_window_baseline_pools_the_previous_revisions(session, database_url, tmp_path):
    config = {"methods": ["ks"], "baseline": "window", "window": 3}
    ingest_and_detect(
        database_url, cpu_history(session, tmp_path, [20.0] * 4 + [60.0], config=config)
    )
    found = _verdicts(session)
    assert [found[(f"r{n}", "ks")].baseline_revisions for n in range(2, 6)] == [1, 2, 3, 3]
    assert found[("r5", "ks")].flagged
    assert found[("r5", "ks")].baseline_revision_id == found[("r4", "ks")].revision_id


def test_pinned_baseline_compares_with_that_revision_or_says_it_is_missing(
    session, database_url, tmp_path
):
    config = {"methods": ["welch_t"], "baseline": "pinned", "pinned": "r2"}
    executions = cpu_history(session, tmp_path, [20.0, 20.0, 20.0, 60.0], config=config)
    ingest_and_detect(database_url, executions)
    found = _verdicts(session)
    assert "pinned revision 'r2'" in found[("r1", "welch_t")].reason
    assert "pinned revision 'r2'" in found[("r2", "welch_t")].reason
    assert found[("r4", "welch_t")].baseline_revision_id == executions[1].revision_id
    assert found[("r4", "welch_t")].flagged and not found[("r3", "welch_t")].flagged


def test_thresholds_in_the_configuration_change_the_verdict(session, database_url, tmp_path):
    config = {"methods": ["ks"], "thresholds": {"ks": {"min_effect": 5.0}}}
    ingest_and_detect(database_url, cpu_history(session, tmp_path, [20.0, 60.0], config=config))
    verdict = _verdicts(session)[("r2", "ks")]
    assert verdict.verdict == "no change" and "below the floor" in verdict.reason
    assert session.scalar(select(func.count()).select_from(Regression)) == 0


def test_reanalysis_after_a_configuration_change_is_idempotent_with_progress(
    session, database_url, tmp_path
):
    executions = cpu_history(session, tmp_path, [20.0, 20.0, 60.0])
    ingest_and_detect(database_url, executions)
    component = session.scalar(select(Component))
    session.add(
        DetectionConfigRow(component_id=component.id, config={"methods": ["mann_whitney", "ks"]})
    )
    session.commit()
    assert reanalyze_component(database_url, component.id, parts=2) == 3
    first = {key: (d.verdict, d.score) for key, d in _verdicts(session).items()}
    assert {method for _, method in first} == {"mann_whitney", "ks"}
    assert reanalyze_component(database_url, component.id, parts=2) == 3
    assert {key: (d.verdict, d.score) for key, d in _verdicts(session).items()} == first
    session.expire_all()
    progress = session.get(Reanalysis, component.id)
    # a unit of progress per revision and part, and one per revision stored in order
    assert (progress.state, progress.done, progress.total) == ("done", 9, 9)
    assert session.scalar(select(func.count()).select_from(Regression)) == 1


def test_host_series_get_no_verdict(session, database_url, tmp_path):
    create_component(session, ComponentCreate(name=NAME))
    executions = [
        add_execution(
            session,
            tmp_path,
            NAME,
            f"r{n}",
            str(n),
            {"cpu_percent": np.full(60, 10.0 * n) + np.arange(60) % 3},
            process="host",
        )
        for n in (1, 2)
    ]
    ingest_and_detect(database_url, executions)
    assert session.scalar(select(func.count()).select_from(Series)) == 1
    assert _verdicts(session) == {}


def test_recorded_nan_and_inf_are_ingested_and_judged_not_enough_data(
    session, database_url, tmp_path
):
    rng = np.random.default_rng(5)
    damaged = rng.normal(20.0, 1.0, 60)
    damaged[::3], damaged[1] = np.nan, np.inf
    executions = cpu_history(session, tmp_path, [20.0, damaged])
    ingest_and_detect(database_url, executions)
    summary = session.scalar(select(Summary).where(Summary.execution_id == executions[1].id))
    assert summary.n == 60 - 20 - 1  # the finite samples only
    assert np.isfinite([summary.mean, summary.std, summary.p50, *summary.sketch]).all()
    verdict = _verdicts(session)[("r2", "ks")]
    assert verdict.verdict == "not enough data" and "NaN/inf" in verdict.reason


def test_a_series_with_no_finite_sample_gets_no_summary_but_a_verdict(
    session, database_url, tmp_path
):
    executions = cpu_history(session, tmp_path, [20.0, np.full(60, np.nan)])
    ingest_and_detect(database_url, executions)
    assert session.scalar(select(Summary).where(Summary.execution_id == executions[1].id)) is None
    verdict = _verdicts(session)[("r2", "ks")]
    assert verdict.verdict == "not enough data" and "NaN/inf" in verdict.reason


def test_a_series_missing_from_recent_revisions_reaches_back_to_where_it_was(
    session, database_url, tmp_path
):
    create_component(session, ComponentCreate(name=NAME))
    session.add(
        DetectionConfigRow(
            component_id=session.scalar(select(Component.id)),
            config={"methods": ["ks"], "baseline": "window", "window": 3},
        )
    )
    session.commit()
    rng = np.random.default_rng(3)
    executions = []
    for number in range(1, 7):
        counters = {"cpu": rng.normal(20, 1, 60)}
        if number in (1, 2, 6):  # 'rare' is recorded by r1, r2 and r6 only
            counters["rare"] = rng.normal(60 if number == 6 else 20, 1, 60)
        executions.append(
            add_execution(session, tmp_path, NAME, f"r{number}", str(number), counters)
        )
    ingest_and_detect(database_url, executions)
    session.expire_all()
    rows = session.execute(
        select(Detection, Series.counter, Revision.title)
        .join(Series, Series.id == Detection.series_id)
        .join(Revision, Revision.id == Detection.revision_id)
    )
    found = {(counter, title): d for d, counter, title in rows}
    rare = found[("rare", "r6")]
    assert (rare.baseline_revisions, rare.baseline_revision_id) == (2, executions[1].revision_id)
    assert rare.flagged
    assert found[("cpu", "r6")].baseline_revisions == 3


def test_reanalysis_with_a_pruned_revision_keeps_its_verdicts_and_matches_detection(
    session, database_url, tmp_path
):
    """The walk keeps flagged verdicts in memory; a revision whose samples are gone keeps its
    stored ones, which must count for the baselines after it exactly as detection reads them."""
    executions = _runs_history(session, tmp_path, [15.0] * 6 + [19.5] * 5)
    ingest_and_detect(database_url, executions)
    pruned = [e for e in executions if e.revision_id == executions[18].revision_id]  # r7
    for execution in pruned:
        samples_path(execution.recording_path).unlink()

    def keyed():
        return {
            key: (d.verdict, d.score, d.baseline_revisions, d.baseline_revision_id)
            for key, d in _verdicts(session).items()
        }

    before = keyed()
    for revision_id in dict.fromkeys(e.revision_id for e in executions):
        detect_revision(database_url, revision_id)  # one by one, flags read from the database
    by_detection = keyed()
    assert {k: v for k, v in by_detection.items() if k[0] == "r7"} == {
        k: v for k, v in before.items() if k[0] == "r7"
    }  # the pruned revision's verdicts stand
    component = session.scalar(select(Component))
    assert reanalyze_component(database_url, component.id, parts=3) == 11
    assert keyed() == by_detection


def test_reanalysis_across_a_busy_spell_longer_than_the_window_matches_detection(
    session, database_url, tmp_path
):
    """Revisions the host was busy in throughout (r7-r10) give no values, but count among the
    revisions a baseline looks through (`lookback`: 6 for a window of 3), in a re-analysis's
    memory as in the database: r11 pools r6 and r5, and a re-analysis stores what judging in
    order stored (its memory skipped them, and pooled r6-r4)."""
    component = create_component(session, ComponentCreate(name=NAME, executions=3))
    config = {"window": 3, "confirm_pairs": 0}
    session.add(DetectionConfigRow(component_id=component.id, config=config))
    session.commit()
    rng = np.random.default_rng(4)
    executions = []
    for number in range(1, 13):
        busy = {"host_percent": 90.0} if 7 <= number <= 10 else {}
        runs = [{"cpu": rng.normal(20 * (1 + rng.normal(0, 0.03)), 2, 40)} for _ in range(3)]
        executions += add_executions(
            session, tmp_path, NAME, f"r{number}", str(number), runs, **busy
        )
    ingest_and_detect(database_url, executions)

    def keyed():
        return {
            key: (d.verdict, d.score, d.baseline_revisions, d.baseline_revision_id)
            for key, d in _verdicts(session).items()
        }

    by_detection = keyed()
    assert by_detection[("r11", "execution_shift")][2:] == (2, executions[17].revision_id)
    assert reanalyze_component(database_url, component.id, parts=2) == 12
    assert keyed() == by_detection
    # and the pages name the revisions it pooled: r12's are r11 and r6, not r11 and r10
    r12 = _verdicts(session)[("r12", "execution_shift")]
    pooled = baseline_revisions(session, r12.series_id, r12.baseline_revision_id, 2)
    assert [revision.title for revision in pooled] == ["r6", "r11"]


def test_a_failure_while_storing_fails_the_reanalysis_with_the_error(
    session, database_url, tmp_path, monkeypatch
):
    from redline.worker import reanalysis_finish

    executions = _runs_history(session, tmp_path, [15.0] * 8)
    ingest_and_detect(database_url, executions)
    before = {key: (d.id, d.verdict, d.score) for key, d in _verdicts(session).items()}
    stored, store = [], reanalysis_finish._store_staged

    def failing_store(session, revision, *args):  # the fourth revision's fails
        if len(stored) == 3:
            raise RuntimeError("disk full")
        stored.append(revision.id)
        store(session, revision, *args)

    monkeypatch.setattr(reanalysis_finish, "_store_staged", failing_store)
    component = session.scalar(select(Component))
    with pytest.raises(RuntimeError, match="disk full"):
        reanalyze_component(database_url, component.id, parts=2)
    session.expire_all()
    progress = session.get(Reanalysis, component.id)
    assert progress.state == "failed" and "RuntimeError: disk full" in progress.error
    assert len(stored) == 3 and progress.stored == 0  # their transaction was rolled back
    assert {key: (d.id, d.verdict, d.score) for key, d in _verdicts(session).items()} == before


def test_reanalysis_skips_an_all_nan_revision_in_baselines_as_detection_does(
    session, database_url, tmp_path
):
    """A revision whose samples are all NaN has no summaries: it is no earlier revision "with
    samples" of the series, for the walk's memory as for the database's answer."""
    cpus = [20.0, 20.0, 20.0, np.full(60, np.nan), 20.0, 20.0, 20.0, 20.0, 60.0]
    executions = cpu_history(session, tmp_path, cpus)
    ingest_and_detect(database_url, executions)

    def keyed():
        return {
            key: (
                d.verdict,
                d.reason,
                d.score,
                d.baseline_revisions,
                d.baseline_revision_id,
            )
            for key, d in _verdicts(session).items()
        }

    by_detection = keyed()
    assert "NaN" in by_detection[("r4", "ks")][1]
    assert by_detection[("r5", "ks")][4] == executions[2].revision_id  # r3, past r4
    component = session.scalar(select(Component))
    assert reanalyze_component(database_url, component.id, parts=2) == 9
    assert keyed() == by_detection


def _second_run_later(session, tmp_path: Path, database_url: str):
    """r1..r6 with one run each at 20 % CPU, then r7 whose first run (20 %) is ingested now and
    whose second run (60 %) only later; returns r7's revision id and a function ingesting it."""
    from redline.server.schemas.revisions import RevisionCreate
    from redline.server.services.revisions import create_revision

    from tests.support.recordings import run_metadata, write_recording

    create_component(session, ComponentCreate(name=NAME, executions=2))
    rng = np.random.default_rng(6)
    revisions = []
    for number in range(1, 8):
        revision = create_revision(
            session,
            RevisionCreate(component=NAME, title=f"r{number}", sort_key=str(number), commit="main"),
        )
        revisions.append(revision)
    session.commit()

    def ingest(revision, job, level: float) -> None:
        name = f"{revision.title}-{job.execution_index}"
        path = write_recording(
            tmp_path / f"{name}.mcap",
            run_metadata(job, NAME, revision.title, revision.sort_key),
            {"cpu": rng.normal(level, 1, 60)},
        )
        execution = uploaded(session, job, path, name)
        session.commit()
        ingest_execution(database_url, execution.id)

    for revision in revisions:
        ingest(revision, revision.jobs[0], 20.0)
    last = revisions[-1]
    return last.id, lambda: ingest(last, last.jobs[1], 60.0)


def test_verdicts_judged_before_an_execution_was_ingested_are_judged_again_when_stored(
    session, database_url, tmp_path
):
    """The parts judged r7 from its first run; its second is ingested before the finishing
    step stores r7: r7 is judged again from what is stored then, not stored stale."""
    from redline.worker.reanalysis import judge_part, plan
    from redline.worker.reanalysis_finish import finish

    revision_id, ingest_second_run = _second_run_later(session, tmp_path, database_url)
    component_id = session.scalar(select(Component.id))
    run = plan(database_url, component_id, parts=2)
    assert not judge_part(database_url, component_id, run, 0)
    assert judge_part(database_url, component_id, run, 1)  # the last part: the end is due
    staged = session.scalars(
        select(StagedDetection).where(StagedDetection.revision_id == revision_id)
    ).all()
    assert staged and not any(row.flagged for row in staged)  # only the first run (20 %) in
    ingest_second_run()  # 60 %: with it, r7 has moved
    assert finish(database_url, component_id, run)
    stored = _verdicts(session)[("r7", "ks")]
    assert stored.flagged and stored.direction == "increase"  # the fresh judgement, not stale
    session.expire_all()
    assert session.get(Reanalysis, component_id).from_database


def test_a_run_ingested_while_its_revision_is_judged_leaves_the_verdict_pending(
    session, database_url, tmp_path, monkeypatch
):
    """A review of the CI gate: ingestion clears `analyzed_at` without the revision's detection
    lock, and a detection that had read r7's samples before then wrote its start time over the
    cleared mark: the verdict read "done" without r7's second run. It stays pending now, and
    the detection queued after the ingestion judges both runs and marks it."""
    from redline.worker import detection

    revision_id, ingest_second_run = _second_run_later(session, tmp_path, database_url)
    for number in range(1, 7):
        detect_revision(database_url, session.scalar(select(Revision.id).where(
            Revision.title == f"r{number}")))  # fmt: skip
    judge = detection.judge_revision

    def judge_then_ingest(*args, **kwargs):
        judged = judge(*args, **kwargs)  # r7 from its first run (20 %)
        ingest_second_run()  # committed while this detection still holds its transaction
        return judged

    monkeypatch.setattr(detection, "judge_revision", judge_then_ingest)
    detect_revision(database_url, revision_id)
    session.expire_all()
    assert not _verdicts(session)[("r7", "ks")].flagged  # judged without the 60 % run
    assert session.get_one(Revision, revision_id).analyzed_at is None  # so: still pending
    monkeypatch.setattr(detection, "judge_revision", judge)
    detect_revision(database_url, revision_id)  # the one the ingestion queued
    session.expire_all()
    assert _verdicts(session)[("r7", "ks")].flagged
    assert session.get_one(Revision, revision_id).analyzed_at is not None


def test_a_run_ingested_while_a_reanalysis_stores_leaves_its_revision_pending(
    session, database_url, tmp_path, monkeypatch
):
    """The finishing step's twin of the test above: r7's staged verdicts (its first run) are
    stored as they are, but r7 is not marked analysed when its second run came in meanwhile.
    (The step's catch-up, left out here, would judge r7 again at once; a run ingested while
    the catch-up judges is the case this shows.)"""
    from redline.worker import reanalysis_finish
    from redline.worker.reanalysis import judge_part, plan

    revision_id, ingest_second_run = _second_run_later(session, tmp_path, database_url)
    component_id = session.scalar(select(Component.id))
    run = plan(database_url, component_id, parts=1)
    assert judge_part(database_url, component_id, run, 0)
    store_staged = reanalysis_finish._store_staged

    def store_then_ingest(session_, revision, *args):
        store_staged(session_, revision, *args)
        if revision.id == revision_id:
            ingest_second_run()

    monkeypatch.setattr(reanalysis_finish, "_store_staged", store_then_ingest)
    monkeypatch.setattr(reanalysis_finish, "_catch_up", lambda *args: None)
    assert reanalysis_finish.finish(database_url, component_id, run)
    session.expire_all()
    marks = dict(session.execute(select(Revision.title, Revision.analyzed_at)).all())
    assert marks.pop("r7") is None
    assert all(at is not None for at in marks.values())
    detect_revision(database_url, revision_id)
    assert _verdicts(session)[("r7", "ks")].flagged


def test_a_run_ingested_into_a_baseline_between_batches_has_the_later_ones_judged_again(
    session, database_url, tmp_path, monkeypatch
):
    """A review: r6 was stored in the finishing step's first batch; a run ingested into r6
    then moved r7's baseline, but r7's own runs were unchanged, so its staged verdicts, judged
    without that run, were stored and r7 marked analysed. Its inputs moved since its part
    began: it is judged again from the database."""
    from redline.worker import reanalysis_finish
    from redline.worker.reanalysis import judge_part, plan

    from tests.support.recordings import run_metadata, write_recording

    r7, _ = _second_run_later(session, tmp_path, database_url)
    r6 = session.get_one(Revision, r7 - 1)
    assert r6.title == "r6"
    component_id = session.scalar(select(Component.id))
    run = plan(database_url, component_id, parts=1)
    assert judge_part(database_url, component_id, run, 0)
    monkeypatch.setattr(reanalysis_finish, "FINISH_BATCH", 6)  # r1..r6, then r7
    monkeypatch.setattr(reanalysis_finish, "_catch_up", lambda *args: None)
    store_batch, batches = reanalysis_finish._store_batch, []

    def then_ingest_into_r6(*args):
        if len(batches) == 1:  # r6 stored and committed: its second run comes in
            job = r6.jobs[1]
            path = write_recording(
                tmp_path / "r6-late.mcap",
                run_metadata(job, NAME, "r6", r6.sort_key),
                {"cpu": np.random.default_rng(9).normal(60.0, 1, 60)},
            )
            execution = uploaded(session, job, path, "r6-late")
            session.commit()
            ingest_execution(database_url, execution.id)
        batches.append(store_batch(*args))
        return batches[-1]

    monkeypatch.setattr(reanalysis_finish, "_store_batch", then_ingest_into_r6)
    assert reanalysis_finish.finish(database_url, component_id, run)
    assert batches[:2] == [True, True]
    stored = _verdicts_of(session, r7)
    detect_revision(database_url, r7)  # from what is stored now
    session.expire_all()
    assert _verdicts_of(session, r7) == stored


def test_a_reanalysis_judges_by_the_configuration_it_was_planned_with(
    session, database_url, tmp_path
):
    """A configuration saved during a run without a re-analysis of its own does not mix into
    it: the parts, and the finishing step judging r7 again from the database (its second run
    was ingested meanwhile), all judge by the configuration as the run was planned."""
    from redline.worker.reanalysis import judge_part, plan
    from redline.worker.reanalysis_finish import finish

    def configure(methods: list[str]) -> None:
        session.merge(DetectionConfigRow(component_id=component_id, config={"methods": methods}))
        session.commit()

    _, ingest_second_run = _second_run_later(session, tmp_path, database_url)
    component_id = session.scalar(select(Component.id))
    configure(["mann_whitney"])
    run = plan(database_url, component_id, parts=2)
    configure(["welch_t"])  # saved with "reanalyze": false
    assert not judge_part(database_url, component_id, run, 0)
    ingest_second_run()
    assert judge_part(database_url, component_id, run, 1)
    assert finish(database_url, component_id, run)
    session.expire_all()
    assert session.get(Reanalysis, component_id).from_database  # r7 judged from the database
    methods = {(title, method) for title, method in _verdicts(session)}
    assert {method for _, method in methods} == {"mann_whitney"}
    assert {title for title, _ in methods} == {f"r{n}" for n in range(1, 8)}
    # each verdict keeps the configuration it was judged by, staged ones and r7's alike (the
    # why-flagged page shows it: a reviewer found the staged ones stored without it)
    kept = session.execute(
        select(Detection.config_id, JudgingConfig.config).outerjoin(
            JudgingConfig, JudgingConfig.id == Detection.config_id
        )
    ).all()
    assert kept and {config_id is not None for config_id, _ in kept} == {True}
    assert {tuple(config["methods"]) for _, config in kept} == {("mann_whitney",)}


def test_a_database_outage_in_a_part_leaves_the_run_going_for_the_task_to_try_again(
    session, database_url, tmp_path, monkeypatch
):
    """A passing outage is no failure of the run: the task tries the part again (tested in
    tests/unit/test_task_retries.py), which takes back what it staged. A part delivered again
    after it finished says the finishing step is due while the run is going (queueing it may
    have failed), and not once the run is done."""
    from redline.worker import reanalysis
    from redline.worker.reanalysis import judge_part, plan
    from redline.worker.reanalysis_finish import finish
    from sqlalchemy.exc import OperationalError

    executions = _runs_history(session, tmp_path, [15.0] * 5 + [19.5] * 3)
    ingest_and_detect(database_url, executions)
    expected = {key: (d.verdict, d.score) for key, d in _verdicts(session).items()}
    component_id = session.scalar(select(Component.id))
    run = plan(database_url, component_id, parts=2)
    judge, calls = reanalysis.judge_revision, []

    def outage_at_the_fifth(*args, **kwargs):
        calls.append(args[1])
        if len(calls) == 5:
            raise OperationalError("SELECT 1", {}, Exception("server closed the connection"))
        return judge(*args, **kwargs)

    monkeypatch.setattr(reanalysis, "judge_revision", outage_at_the_fifth)
    with pytest.raises(OperationalError):
        judge_part(database_url, component_id, run, 0)
    session.expire_all()
    assert session.get(Reanalysis, component_id).state == "running"
    assert not judge_part(database_url, component_id, run, 0)  # tried again: all of it
    assert judge_part(database_url, component_id, run, 1)
    assert judge_part(database_url, component_id, run, 1)  # again: the end is still due
    assert finish(database_url, component_id, run)
    assert not judge_part(database_url, component_id, run, 1)  # the run is done
    assert {key: (d.verdict, d.score) for key, d in _verdicts(session).items()} == expected
    session.expire_all()
    progress = session.get(Reanalysis, component_id)
    assert (progress.state, progress.done) == ("done", progress.total)


def test_a_superseded_reanalysis_stops_and_the_newer_one_stores_everything(
    session, database_url, tmp_path
):
    from redline.worker.reanalysis import judge_part, plan
    from redline.worker.reanalysis_finish import finish

    executions = _runs_history(session, tmp_path, [15.0] * 5 + [19.5] * 3)
    ingest_and_detect(database_url, executions)
    expected = {key: (d.verdict, d.score) for key, d in _verdicts(session).items()}
    component_id = session.scalar(select(Component.id))
    old = plan(database_url, component_id, parts=2)
    assert not judge_part(database_url, component_id, old, 0)
    new = plan(database_url, component_id, parts=1)  # a configuration changed again
    assert not judge_part(database_url, component_id, old, 1)  # superseded: it stops
    assert not finish(database_url, component_id, old)
    assert judge_part(database_url, component_id, new, 0)
    assert finish(database_url, component_id, new)
    # delivered again after the end: done already, nothing stored twice (the caller renders
    # the charts and scans the alerts again, which is harmless)
    assert finish(database_url, component_id, new)
    assert {key: (d.verdict, d.score) for key, d in _verdicts(session).items()} == expected
    session.expire_all()
    assert session.get(Reanalysis, component_id).state == "done"
    assert session.scalar(select(func.count()).select_from(StagedRevision)) == 0


def test_bulk_insert_refuses_an_over_long_string_rather_than_cutting_it(
    session, database_url, tmp_path
):
    from redline.server.db import bulk_insert
    from sqlalchemy.exc import DataError

    ingest_and_detect(database_url, cpu_history(session, tmp_path, [20.0, 20.0]))
    row = session.scalars(select(Detection)).first()
    values = {c.name: getattr(row, c.name) for c in Detection.__table__.columns if c.name != "id"}
    values["method"] = "m" * 60  # the column holds 50
    with pytest.raises(DataError, match="too long"):
        bulk_insert(session, Detection.__table__, [values])
    session.rollback()


def test_a_part_delivered_twice_never_leaves_a_revision_without_its_series_verdicts(
    session, database_url, tmp_path
):
    """A review: a copy of a part delivered again took the first copy's staging back, and the
    finishing step then stored revisions with only the other parts' series."""
    from redline.worker.reanalysis import judge_part, plan
    from redline.worker.reanalysis_finish import finish

    executions = _runs_history(session, tmp_path, [15.0] * 4)
    ingest_and_detect(database_url, executions)
    expected = {key: (d.verdict, d.score) for key, d in _verdicts(session).items()}
    component_id = session.scalar(select(Component.id))
    run = plan(database_url, component_id, parts=2)
    assert not judge_part(database_url, component_id, run, 0)
    staged = session.scalar(select(func.count()).select_from(StagedDetection))
    assert not judge_part(database_url, component_id, run, 0)  # again, once done: nothing redone
    assert session.scalar(select(func.count()).select_from(StagedDetection)) == staged
    assert judge_part(database_url, component_id, run, 1)
    # the second part's staging taken back (as a copy starting again would) before the end
    session.execute(delete(StagedRevision).where(StagedRevision.part == 1))
    session.commit()
    with pytest.raises(RuntimeError, match=r"1 of 2 parts staged it"):
        finish(database_url, component_id, run)
    session.expire_all()
    assert session.get(Reanalysis, component_id).state == "failed"
    assert {key: (d.verdict, d.score) for key, d in _verdicts(session).items()} == expected


def test_a_revision_reported_during_a_reanalysis_is_judged_when_it_ends(
    session, database_url, tmp_path
):
    """A review: revisions reported while a re-analysis ran were judged live against earlier
    verdicts of the old configuration, and never again."""
    from redline.worker.reanalysis import judge_part, plan
    from redline.worker.reanalysis_finish import finish

    executions = _runs_history(session, tmp_path, [15.0] * 6)
    ingest_and_detect(database_url, executions)
    component_id = session.scalar(select(Component.id))
    run = plan(database_url, component_id, parts=1)
    assert judge_part(database_url, component_id, run, 0)
    rng = np.random.default_rng(8)
    late = add_executions(
        session, tmp_path, NAME, "r7", "7", [{"cpu": rng.normal(15.0, 1.5, 40)} for _ in range(3)]
    )
    for execution in late:
        ingest_execution(database_url, execution.id)  # its detection message lost, say
    r7 = late[0].revision_id
    session.expire_all()
    assert session.get_one(Revision, r7).analyzed_at is None and not _verdicts_of(session, r7)
    assert finish(database_url, component_id, run)
    session.expire_all()
    judged = _verdicts_of(session, r7)
    assert judged and session.get_one(Revision, r7).analyzed_at is not None
    for revision_id in dict.fromkeys(e.revision_id for e in [*executions, *late]):
        detect_revision(database_url, revision_id)  # revision by revision, as detection does
    session.expire_all()
    assert _verdicts_of(session, r7) == judged


def _verdicts_of(session, revision_id: int) -> list[tuple]:
    return [
        (d.series_id, d.method, d.verdict, d.score, d.baseline_revision_id)
        for d in session.scalars(
            select(Detection)
            .where(Detection.revision_id == revision_id)
            .order_by(Detection.series_id, Detection.method)
        )
    ]
