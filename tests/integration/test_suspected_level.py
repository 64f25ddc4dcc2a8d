"""The revisions right after a flag, while the revisions after it have not yet decided it, on
real Postgres through the worker (`redline.detect.suspected`): one execution a revision, as a
component's default. Before, every flag restarted the baseline at once, and the next two
revisions were judged against the flagged one alone: "not enough data", a CI gate blind right
where a noise flag had just fallen (a trial's README commit, flagged as an improvement); and once
a change held, the three after them against its few values, short of the six needed."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from redline.detect.confirmation import BY_PAIRS
from redline.detect.suspected import AT_NEW_LEVEL, BEFORE_SUSPECTED
from redline.server.models import Detection, Revision
from redline.server.schemas.components import ComponentCreate
from redline.server.services.components import create_component
from redline.worker.ingest import ingest_execution
from redline.worker.onward import judge_onward
from redline.worker.reanalysis import reanalyze_component
from sqlalchemy import select

from tests.support.history import add_executions, ingest_and_detect

NAME = "builder"


def _history(
    session,
    database_url: str,
    tmp_path: Path,
    levels: list[float],
    executions: int = 1,
    judged: Callable[[str], None] = lambda _title: None,
    between: float = 0.01,
) -> None:
    """Revisions r1.. of ``executions`` each around ``levels`` (2 % noise in the samples, a
    fixed ``between`` between runs), judged one by one as the service judges them (with more
    than one execution, by the worker's walk: `judge_onward`); ``judged`` is told each
    revision's title once it is judged."""
    create_component(session, ComponentCreate(name=NAME, executions=executions))
    rng = np.random.default_rng(11)
    wobble = [0.0, between, -between, between / 2, -between / 2]
    for number, level in enumerate(levels, start=1):
        runs = [
            {"cpu": rng.normal(level * (1 + wobble[(number + i) % 5]), level * 0.02, 60)}
            for i in range(executions)
        ]
        made = add_executions(session, tmp_path, NAME, f"r{number}", str(number), runs)
        if executions == 1:
            ingest_and_detect(database_url, made)
        else:
            for execution in made:
                ingest_execution(database_url, execution.id)
            judge_onward(database_url, made[0].revision_id)
        judged(f"r{number}")
    session.expire_all()


def _verdicts(session) -> dict[str, Detection]:
    rows = session.execute(
        select(Detection, Revision.title)
        .join(Revision, Revision.id == Detection.revision_id)
        .where(Detection.method == "execution_shift")
    )
    return {title: detection for detection, title in rows}


def _flagged_up_a_third(session, found: Detection, reason: str, newest: str) -> None:
    """``found`` is a change of about +30 %, its reason saying ``reason``, judged against a
    baseline whose newest revision is ``newest``."""
    assert found.flagged and found.direction == "increase", (found.verdict, found.reason)
    assert 0.2 < (found.effect or 0) < 0.4
    assert reason in found.reason, found.reason
    base = session.get(Revision, found.baseline_revision_id)
    assert base is not None and base.title == newest


def _reanalysed_alike(session, database_url: str, verdicts: dict[str, Detection]) -> None:
    """A re-analysis of the component judges every revision as the live path did."""
    before = {title: (d.verdict, d.reason) for title, d in verdicts.items()}
    component_id = session.scalars(select(Revision.component_id)).first()
    reanalyze_component(database_url, component_id)
    session.expire_all()
    assert {title: (d.verdict, d.reason) for title, d in _verdicts(session).items()} == before


def test_a_regression_right_after_a_noise_flag_is_flagged_not_left_undecided(
    session, database_url, tmp_path
):
    """r9 runs low (flagged as an improvement); r10 makes a real +30 %."""
    _history(session, database_url, tmp_path, [20.0] * 8 + [14.0] + [26.0] * 3)
    verdicts = _verdicts(session)
    assert verdicts["r9"].flagged and verdicts["r9"].direction == "decrease"
    # judged against the level before r9, r9 left out
    _flagged_up_a_third(session, verdicts["r10"], f"{BEFORE_SUSPECTED} r9", "r8")
    _reanalysed_alike(session, database_url, verdicts)


def test_the_revisions_after_a_noise_flag_are_judged_against_the_level_before_it(
    session, database_url, tmp_path
):
    _history(session, database_url, tmp_path, [20.0] * 8 + [14.0] + [20.0] * 3)
    verdicts = _verdicts(session)
    assert verdicts["r9"].flagged
    for title in ("r10", "r11"):
        assert verdicts[title].verdict == "no change", (title, verdicts[title].reason)
        assert f"{BEFORE_SUSPECTED} r9" in verdicts[title].reason
    # by r12 the two after it have decided: a spike, and the baseline reads on past it
    assert verdicts["r12"].verdict == "no change"
    assert BEFORE_SUSPECTED not in verdicts["r12"].reason


def test_a_revision_that_holds_a_suspected_change_is_not_flagged_again(
    session, database_url, tmp_path
):
    """r9 makes a real +30 %: r10, at its level, shows the same change against the level before
    it, which is r9's change holding, not a new one."""
    _history(session, database_url, tmp_path, [20.0] * 8 + [26.0] * 4)
    verdicts = _verdicts(session)
    assert verdicts["r9"].flagged and verdicts["r9"].direction == "increase"
    r10 = verdicts["r10"]
    assert r10.verdict == "not enough data", r10.reason
    assert "against the level before the change flagged at r9 it shows that change" in (r10.reason)
    assert not any(d.flagged for t, d in verdicts.items() if t != "r9")


def test_once_a_change_held_the_revisions_after_it_are_judged_at_its_new_level(
    session, database_url, tmp_path
):
    """r9 makes +30 %, which r10 and r11 hold; r12 adds another +30 %. Before, r12 was judged
    against r9-r11 alone (3 values, needs 6: "not enough data"), so the second change passed
    CI unjudged and was pooled into the new level; now the new level is judged with the noise
    of the one before it (`ExecutionShift.at_new_level`)."""
    _history(session, database_url, tmp_path, [20.0] * 8 + [26.0] * 3 + [34.0] + [34.0] * 2)
    verdicts = _verdicts(session)
    assert verdicts["r9"].flagged and verdicts["r9"].confirmation == "held"
    _flagged_up_a_third(session, verdicts["r12"], f"{AT_NEW_LEVEL} r9 (3 value(s))", "r11")
    assert verdicts["r12"].baseline_revisions == 3
    flagged = sorted(title for title, d in verdicts.items() if d.flagged)
    assert flagged == ["r12", "r9"], flagged
    _reanalysed_alike(session, database_url, verdicts)


def test_a_revision_at_a_held_change_s_level_is_no_change_not_undecided(
    session, database_url, tmp_path
):
    _history(session, database_url, tmp_path, [20.0] * 8 + [26.0] * 7)
    verdicts = _verdicts(session)
    for title in ("r12", "r13", "r14"):
        assert verdicts[title].verdict == "no change", (title, verdicts[title].reason)
        assert f"{AT_NEW_LEVEL} r9" in verdicts[title].reason
    assert verdicts["r15"].verdict == "no change"  # r9-r14, six values: judged by them alone
    assert AT_NEW_LEVEL not in verdicts["r15"].reason


@pytest.mark.parametrize("executions", [3, 1])
def test_a_step_back_right_after_an_improvement_is_flagged_at_its_own_revision(
    session, database_url, tmp_path, executions
):
    """A trial's commit raised the CPU by 19 % right after an improvement was flagged (three
    executions a revision): judged while that improvement was undecided, it showed it against
    the level before it ("not enough data"), passed CI, and was pooled into the new level,
    never flagged. r9 falls 40 %, r10 rises 25 % from there (still 25 % under the level before
    r9): flagged at r10, against r9's level, with the noise of the level before r9 (r9's level
    is one value with one execution a revision). A spike's return to the old level is no
    change."""
    levels = [20.0] * 8 + [12.0] + [15.0] * 3
    _history(session, database_url, tmp_path, levels, executions=executions)
    verdicts = _verdicts(session)
    assert verdicts["r9"].flagged and verdicts["r9"].direction == "decrease"
    r10 = verdicts["r10"]
    assert r10.flagged and r10.direction == "increase", (r10.verdict, r10.reason)
    assert 0.15 < (r10.effect or 0) < 0.35
    assert f"{BEFORE_SUSPECTED} r9 it still shows that change" in r10.reason, r10.reason
    base = session.get(Revision, r10.baseline_revision_id)
    assert base is not None and base.title == "r9"
    assert not any(d.flagged for t, d in verdicts.items() if t not in ("r9", "r10"))
    _reanalysed_alike(session, database_url, verdicts)


def test_a_spike_that_returns_is_no_change_with_three_executions_a_revision(
    session, database_url, tmp_path
):
    _history(session, database_url, tmp_path, [20.0] * 8 + [12.0] + [20.0] * 3, executions=3)
    verdicts = _verdicts(session)
    assert verdicts["r9"].flagged
    for title in ("r10", "r11", "r12"):
        assert not verdicts[title].flagged, (title, verdicts[title].reason)


def _confirmed_as_pairs_would(session, titles: set[str]) -> Callable[[str], None]:
    """Told each revision as it is judged (`_history`'s ``judged``): marks the flags of
    ``titles`` "confirmed by 2 of 2 pairs" as their pairs would (no agent runs here; the pairs'
    own judging is tested in `tests/integration/test_confirmation_runs.py`)."""

    def confirm(title: str) -> None:
        if title not in titles:
            return
        session.expire_all()
        found = _verdicts(session)[title]
        assert found.flagged and found.confirmation == "suspected", (found.verdict, found.reason)
        found.confirmation, found.confirmation_reason = "held", f"{BY_PAIRS} 2 of 2 pairs"
        session.commit()

    return confirm


def test_a_revert_right_after_a_confirmed_regression_restarts_the_baseline_there(
    session, database_url, tmp_path
):
    """A trial's regression, confirmed by 2 of 2 pairs, was reverted by the next commit: judged
    against the level before the regression ("no change"), the revert was pooled with the
    regression's level into the next commit's baseline, and a +30 % commit after it passed CI
    (exit 0, "no change -10.8 %"). Once its pairs confirmed a flag, the revisions after it are
    judged against its level: the revert is a change for the better, and the +30 % a change for
    the worse. r9 +50 % (confirmed as its pairs would), r10 back to the old level, r11 +30 %."""
    levels = [20.0] * 8 + [30.0, 20.0] + [26.0] * 2
    confirm = _confirmed_as_pairs_would(session, {"r9"})
    _history(session, database_url, tmp_path, levels, 3, confirm)
    verdicts = _verdicts(session)
    r10, r11 = verdicts["r10"], verdicts["r11"]
    assert r10.flagged and r10.direction == "decrease", (r10.verdict, r10.reason)
    assert f"{AT_NEW_LEVEL} r9" in r10.reason, r10.reason
    assert r11.flagged and r11.direction == "increase", (r11.verdict, r11.reason)
    assert 0.2 < (r11.effect or 0) < 0.4, r11.effect
    # the revert's flag undecided yet, and back at the level before r9: judged against that
    # level, named by the revert (its pairs run r11 against r10)
    assert "before the change confirmed at r9, to which the change flagged at r10" in r11.reason
    base = session.get(Revision, r11.baseline_revision_id)
    assert base is not None and base.title == "r10", base.title if base else None


def test_a_step_after_reverting_a_confirmed_regression_is_flagged_against_the_revert(
    session, database_url, tmp_path
):
    """A trial's history: confirmed regressions at r9 (+67 %), r11 (+20 %) and r12 (x2.5), the
    last reverted by r13 (flagged as an improvement), then a +28 % step at r14. The revert's
    level before it was read past r12's and r11's confirmed flags as if undecided, back to
    r10's: against it r14 "showed the change" (+49.6 %, the other way from the revert) and was
    "not enough data"; pooled into r15's baseline, the step was never flagged. Now r12's level
    (three values) is the one before the revert, judged with the spread of the first long level
    before it (r1-r8: read past the short confirmed levels of r11 and r9)."""
    levels = [3.0] * 8 + [5.0, 3.0, 3.6, 9.0, 3.5, 4.5, 4.5, 4.5]
    confirm = _confirmed_as_pairs_would(session, {"r9", "r11", "r12"})
    _history(session, database_url, tmp_path, levels, 3, confirm)
    verdicts = _verdicts(session)
    r13, r14 = verdicts["r13"], verdicts["r14"]
    assert r13.flagged and r13.direction == "decrease", (r13.verdict, r13.reason)
    assert r14.flagged and r14.direction == "increase", (r14.verdict, r14.reason)
    assert 0.2 < (r14.effect or 0) < 0.35, r14.effect
    assert f"{BEFORE_SUSPECTED} r13 it still shows that change" in r14.reason, r14.reason
    base = session.get(Revision, r14.baseline_revision_id)
    assert base is not None and base.title == "r13", base.title if base else None
    # r15, at r14's level, holds r14's change as the level before r14 reads it (past r13, which
    # may yet be a spike): undecided, as any revision that holds a suspected change; r16 is
    # judged by the six values from r14 on
    r15, r16 = verdicts["r15"], verdicts["r16"]
    assert r15.verdict == "not enough data" and "r14 it shows that change" in r15.reason, r15
    assert r16.verdict == "no change", r16.reason


@pytest.mark.parametrize(
    ("after", "verdict"), [(23.0, "change"), (20.0, "no change")], ids=["reland", "unchanged"]
)
def test_after_a_confirmed_regression_s_revert_a_commit_is_judged_against_the_level_reverted_to(
    session, database_url, tmp_path, after, verdict
):
    """A third trial (three executions a revision): a regression doubling the work, confirmed
    by its pairs, its exact revert, then a reland at +30 % over the original: the reland was
    judged against the revert's three values with the noise around them ("not enough data",
    it "showed the change" against the confirmed level), the next commit pooled it unflagged.
    The revert returned to the level before the regression: a commit after it is judged against
    that level, which holds enough values to judge by, and an unchanged one is no change there
    (it was "not enough data"). r9 x2, r10 its revert, r11 ``after`` (+15 %, which the revert's
    three values alone do not show beyond 6 % between runs)."""
    levels = [20.0] * 8 + [40.0, 20.0, after]
    confirm = _confirmed_as_pairs_would(session, {"r9"})
    _history(session, database_url, tmp_path, levels, 3, confirm, between=0.06)
    verdicts = _verdicts(session)
    r11 = verdicts["r11"]
    assert r11.verdict == verdict, (r11.verdict, r11.reason)
    assert "the change confirmed at r9, to which the change flagged at r10 returned" in r11.reason
    # named by the revert, at that level: a range from r8 would join r9's regression (a fourth
    # trial's reland did, and moved its bad revision), silent once it is triaged fixed
    base = session.get(Revision, r11.baseline_revision_id)
    assert base is not None and base.title == "r10", base.title if base else None
    if verdict == "change":
        assert r11.direction == "increase" and 0.1 < (r11.effect or 0) < 0.3, r11.effect
        assert r11.regression_id not in (None, verdicts["r9"].regression_id)


def test_a_revert_on_a_noisy_component_is_flagged_so_the_reland_after_it_is_judged_alone(
    session, database_url, tmp_path
):
    """A fourth trial, on a noisy component (three executions a revision, 15 % between runs
    here): a regression doubling the work, confirmed by its pairs, then its revert: "no change
    -49.5 %" against the regression's three values (score 0.95), pooled with them into the next
    commit's baseline, against which the reland (+30 %) read "no change -6.7 %". Back at the
    level before the regression, the revert is flagged as a return (for the better: the
    revisions after it decide), and the reland is judged against the level it returned to,
    named by the revert. r9 x2, r10 its revert, r11 +30 %."""
    levels = [20.0] * 8 + [40.0, 20.0, 26.0]
    confirm = _confirmed_as_pairs_would(session, {"r9"})
    _history(session, database_url, tmp_path, levels, 3, confirm, between=0.15)
    verdicts = _verdicts(session)
    r10, r11 = verdicts["r10"], verdicts["r11"]
    assert r10.flagged and r10.direction == "decrease", (r10.verdict, r10.reason)
    assert "back at the level before the change confirmed at r9" in r10.reason, r10.reason
    assert "the change confirmed at r9, to which the change flagged at r10 returned" in r11.reason
    assert 0.2 < (r11.effect or 0) < 0.5, (r11.effect, r11.reason)  # +30 % and its noise
    base = session.get(Revision, r11.baseline_revision_id)
    assert base is not None and base.title == "r10", base.title if base else None
