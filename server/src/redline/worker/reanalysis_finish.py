"""The end of a re-analysis (`redline.worker.reanalysis`) and what its steps share: the run's
row (`current_run`: is this run still the component's, and going?), its failure, the revisions
planned.

`finish` stores the verdicts the parts staged revision by revision in sort-key order: each
revision's verdicts replaced and grouped into regressions as detection does, `FINISH_BATCH`
revisions a transaction, recording how far it got (a finishing step delivered again goes on
from there); a revision whose executions changed since its parts judged it is judged again from
the database, and so is every revision after it. At the end the revisions reported during the
run, or whose executions changed after they were stored, are judged again (`_catch_up`), then
the confirmations are settled once for the component (they depend on stored data only).
"""

from __future__ import annotations

import logging
from collections import defaultdict
from collections.abc import Collection

from redline.detect.config import DetectionConfig
from redline.server.db import lock_revision, session_scope
from redline.server.models import (
    Component,
    Detection,
    Execution,
    Reanalysis,
    Revision,
    StagedDetection,
    StagedRevision,
    utcnow,
)
from redline.server.services.analysed import inputs_seen, mark_analysed
from redline.server.services.detection_config import component_config, judging_config_id
from redline.server.services.reach import ingested_executions
from redline.worker.confirm_runs import settle_pending_pairs
from redline.worker.confirmation import confirm_by_history
from redline.worker.detection import judge_revision, store
from redline.worker.found_late import still_moved
from redline.worker.grouping import group_revision
from sqlalchemy import delete, select, text, update
from sqlalchemy.exc import InterfaceError, OperationalError
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)

#: revisions the finishing step stores in one transaction
FINISH_BATCH = 50
#: a revision whose samples are gone: its stored results stand
KEPT = "kept"
#: the columns a staged verdict gives its `Detection`
DETECTION_COLUMNS = (
    "series_id, revision_id, baseline_revision_id, baseline_revisions, method, verdict, reason, "
    "score, p_value, effect, direction, flagged, confirmation, confirmation_reason, created"
)


class Superseded(Exception):
    """A newer re-analysis of the component began: this one's work stops."""


def revisions_with_data(session: Session, component_id: int) -> list[int]:
    return list(
        session.scalars(
            select(Revision.id)
            .where(Revision.component_id == component_id)
            .where(
                select(Execution.id)
                .where(
                    Execution.id.in_(ingested_executions()), Execution.revision_id == Revision.id
                )
                .exists()
            )
            .order_by(Revision.order_key, Revision.id)
        )
    )


def current_run(session: Session, component_id: int, run: int, lock: bool = False) -> Reanalysis:
    """The re-analysis row, if ``run`` is still the component's current one."""
    query = select(Reanalysis).where(Reanalysis.component_id == component_id)
    if lock:
        query = query.with_for_update()
    row = session.scalar(query.execution_options(populate_existing=True))
    if row is None or row.run != run:
        raise Superseded(f"component {component_id}: re-analysis {run} was superseded")
    if row.state == "failed":  # a sibling part or the finishing step failed: the run is over
        raise Superseded(f"component {component_id}: re-analysis {run} failed: {row.error}")
    return row


def run_config(session: Session, row: Reanalysis) -> DetectionConfig:
    """The configuration the run judges by: the component's as it was planned. A change saved
    during the run without a re-analysis of its own (``"reanalyze": false``) therefore does not
    mix two configurations in one history; it applies from the next revision judged after."""
    if row.config is None:
        return component_config(session, row.component_id)
    return DetectionConfig.parse(row.config)


#: a database that went away for a moment: the task is tried again, the run is not failed
TRANSIENT = (OperationalError, InterfaceError)


def fail_run(database_url: str, component_id: int, run: int, error: BaseException) -> None:
    """The run's row must not stay "running", whatever stopped it (unless a newer run began)."""
    with session_scope(database_url) as session:
        session.execute(
            update(Reanalysis)
            .where(Reanalysis.component_id == component_id, Reanalysis.run == run)
            .values(state="failed", error=f"{type(error).__name__}: {error}", finished=utcnow())
        )


def joined(executions: tuple[int, ...]) -> str:
    return ",".join(str(execution) for execution in executions)


def finish(database_url: str, component_id: int, run: int) -> bool:
    """Store the staged verdicts revision by revision in order, then settle confirmations; True
    when this call ended the re-analysis (False: superseded, or ended by another)."""
    try:
        with session_scope(database_url) as session:
            planned = list(current_run(session, component_id, run).revisions)  # read once
        while True:
            with session_scope(database_url) as session:
                if not _store_batch(session, component_id, run, planned):
                    break
        with session_scope(database_url) as session:
            _catch_up(session, component_id, run, planned)
        with session_scope(database_url) as session:
            session.execute(
                select(Component.id).where(Component.id == component_id).with_for_update()
            )
            row = current_run(session, component_id, run, lock=True)
            if row.state == "done":  # delivered again after its end: the charts, alerts again
                return True
            if row.state != "running":
                return False
            settle_pending_pairs(session, component_id)
            config = run_config(session, row)
            confirm_by_history(session, component_id, config.confirm_revisions, config.alarming)
            for table in (StagedDetection, StagedRevision):
                session.execute(delete(table).where(table.component_id == component_id))
            row.state, row.finished = "done", utcnow()
    except Superseded as exc:
        log.info("%s: its finishing step stops", exc)
        return False
    except TRANSIENT:
        raise  # the task tries again (`redline.worker.tasks`), going on from the last batch
    except BaseException as exc:
        fail_run(database_url, component_id, run, exc)
        raise
    log.info("component %s: re-analysis %d done", component_id, run)
    return True


def _catch_up(session: Session, component_id: int, run: int, planned: list[int]) -> None:
    """What the history gained while the re-analysis ran, judged again from the database, as
    detection does: every revision from the first one that was not planned (reported during
    it) or whose ingested executions are not those its parts judged. Live detection judged
    those against earlier verdicts of the old configuration, or the finishing step stored
    verdicts whose baselines lacked an execution ingested since (a review)."""
    row = current_run(session, component_id, run)
    if row.state != "running":
        return
    judged = dict(
        session.execute(
            select(StagedRevision.revision_id, StagedRevision.executions).where(
                StagedRevision.component_id == component_id, StagedRevision.run == run
            )
        ).all()
    )
    now = revisions_with_data(session, component_id)
    ingested: dict[int, list[int]] = defaultdict(list)
    for execution_id, revision_id in session.execute(
        select(Execution.id, Execution.revision_id)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(Revision.component_id == component_id, Execution.id.in_(ingested_executions()))
        .order_by(Execution.id)
    ):
        ingested[revision_id].append(execution_id)
    first = next(
        (
            index
            for index, revision_id in enumerate(now)
            if index >= len(planned)
            or planned[index] != revision_id
            or judged.get(revision_id) not in (KEPT, joined(tuple(ingested[revision_id])))
        ),
        None,
    )
    if first is None:
        return
    log.info("component %s: %d revisions changed during re-analysis %d, judged again",
             component_id, len(now) - first, run)  # fmt: skip
    for revision_id in now[first:]:  # the revisions' locks before the component's
        lock_revision(session, revision_id)
    session.execute(select(Component.id).where(Component.id == component_id).with_for_update())
    config = run_config(session, row)
    began, seen = utcnow(), inputs_seen(session, now[first:])  # before the samples
    for revision_id in now[first:]:
        fresh = judge_revision(session, revision_id, config=config)
        if fresh is not None:
            store(session, session.get_one(Revision, revision_id), fresh.rows, config=config)
    mark_analysed(session, seen, began)


def _store_batch(session: Session, component_id: int, run: int, planned: list[int]) -> bool:
    """The next `FINISH_BATCH` of the ``planned`` revisions stored; False when none is left."""
    row = current_run(session, component_id, run)
    start = row.stored
    batch = planned[start : start + FINISH_BATCH]
    if not batch or row.state != "running":
        return False
    # the revisions' locks before the component's, in the order detection takes them
    for revision_id in batch:
        lock_revision(session, revision_id)
    session.execute(select(Component.id).where(Component.id == component_id).with_for_update())
    row = current_run(session, component_id, run, lock=True)
    if row.stored != start:
        return True  # another finishing step stored these meanwhile
    judged_from: dict[int, set[str]] = {}
    staged: dict[int, int] = defaultdict(int)  # how many parts staged each revision
    began_with: dict[int, set[int | None]] = defaultdict(set)  # its inputs as the parts began
    for revision_id, executions, inputs in session.execute(
        select(StagedRevision.revision_id, StagedRevision.executions, StagedRevision.inputs).where(
            StagedRevision.component_id == component_id,
            StagedRevision.run == run,
            StagedRevision.revision_id.in_(batch),
        )
    ):
        judged_from.setdefault(revision_id, set()).add(executions)
        staged[revision_id] += 1
        began_with[revision_id].add(inputs)
    began, seen = utcnow(), inputs_seen(session, batch)  # before what was ingested is read
    ingested: dict[int, list[int]] = defaultdict(list)
    for execution_id, revision_id in session.execute(
        select(Execution.id, Execution.revision_id)
        .where(Execution.revision_id.in_(batch), Execution.id.in_(ingested_executions()))
        .order_by(Execution.id)  # as `ingested_runs` lists them
    ):
        ingested[revision_id].append(execution_id)
    flagged = set(
        session.scalars(
            select(StagedDetection.revision_id)
            .distinct()
            .where(
                StagedDetection.component_id == component_id,
                StagedDetection.run == run,
                StagedDetection.revision_id.in_(batch),
                StagedDetection.flagged,
            )
        )
    )
    revisions = {r.id: r for r in session.scalars(select(Revision).where(Revision.id.in_(batch)))}
    config = run_config(session, row)
    config_id = judging_config_id(session, component_id, config)
    fresh, stored = row.from_database, set()
    for revision_id in batch:
        revision = revisions.get(revision_id)
        if revision is None:
            continue  # deleted since it was planned
        said = judged_from.get(revision_id, set())
        if staged.get(revision_id, 0) != row.parts:
            # a copy of a part delivered again while the first still ran took the first's
            # staging back: storing now would leave that part's series without verdicts
            raise RuntimeError(
                f"revision {revision_id}: {staged.get(revision_id, 0)} of {row.parts} parts "
                "staged it (a part ran twice at once); request the re-analysis again"
            )
        if said == {KEPT}:
            continue
        moved = began_with[revision_id] - {None, seen.get(revision_id)}  # None: staged before
        if fresh or moved or said != {joined(tuple(ingested[revision_id]))}:
            # an execution was ingested (or one went) since the parts judged it, or into an
            # earlier revision in its reach (its inputs moved): judged again from what is stored
            # now, as detection does, and so is every revision after it
            fresh = True
            judged = judge_revision(session, revision_id, config=config)
            if judged is not None:
                store(session, revision, judged.rows, config=config)
                stored.add(revision_id)
            continue
        _store_staged(session, revision, run, config.alarming, revision_id in flagged, config_id)
        stored.add(revision_id)
    mark_analysed(session, {r: seen[r] for r in stored if r in seen}, began)
    row.stored, row.done, row.from_database = start + len(batch), row.done + len(batch), fresh
    return True


def _store_staged(
    session: Session,
    revision: Revision,
    run: int,
    alarming: Collection[str],
    flagged: bool,
    config_id: int,
) -> None:
    """Replace the revision's verdicts with its staged ones, judged by the kept configuration
    ``config_id``, by series, each series' methods in
    order (the order detection stores the flagged ones in, which grouping follows), and group
    its changes into regressions: when it has ``flagged`` ones, or when the verdicts replaced
    belonged to regressions (which may be left empty); otherwise grouping finds nothing to do."""
    staged = select(StagedDetection).where(
        StagedDetection.component_id == revision.component_id,
        StagedDetection.run == run,
        StagedDetection.revision_id == revision.id,
    )
    fresh = session.execute(
        staged.with_only_columns(
            StagedDetection.series_id,
            StagedDetection.method,
            StagedDetection.verdict,
            StagedDetection.reason,
        )
    )
    kept = still_moved(session, revision.id, fresh.all())  # its regression keeps its id
    emptied = session.scalars(
        delete(Detection)
        .where(Detection.revision_id == revision.id, Detection.id.not_in(list(kept.values())))
        .returning(Detection.regression_id)
    ).all()
    session.execute(  # all but the kept verdicts' series and methods
        text(
            f"INSERT INTO detection ({DETECTION_COLUMNS}, config_id) "
            f"SELECT {DETECTION_COLUMNS}, :config FROM staged_detection s "
            "WHERE component_id = :component AND run = :run AND revision_id = :revision "
            "AND NOT EXISTS (SELECT 1 FROM detection d WHERE d.revision_id = s.revision_id "
            "AND d.series_id = s.series_id AND d.method = s.method) "
            "ORDER BY series_id, id"
        ),
        {
            "component": revision.component_id,
            "run": run,
            "revision": revision.id,
            "config": config_id,
        },
    )
    if flagged or any(regression is not None for regression in emptied):
        group_revision(session, revision, alarming)
