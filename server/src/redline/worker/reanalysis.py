"""Re-analysis of a component's whole history (after its detection configuration changed), split
by series across workers.

A series is judged against its own history alone, so a re-analysis fans out by series: `plan`
records the revisions to judge and how many parts share the series; each part (`judge_part`, a
task of its own on any worker) walks every planned revision in sort-key order and judges the
series whose id, modulo the parts, is its index, carrying what the baselines need of the earlier
revisions in memory (`Walk`), and stages its verdicts (`StagedDetection`, and a `StagedRevision`
naming the executions each revision was judged from). The part that completes the set queues the
finishing step (Postgres decides which, under the re-analysis row's lock: a Celery chord would
need a result backend, which Redline does without). `finish` stores the staged verdicts revision
by revision in order, grouping each revision's changes into regressions as detection does, then
settles the confirmations once for the component (they depend on stored data only,
`redline.worker.confirmation`): the verdicts, regressions and confirmations are those detection
revision by revision gives (tested).

Idempotent and resumable: a part redelivered after its worker died stages its series again (its
progress taken back first: ``done`` counts what is staged and stored, in the same transactions);
the finishing step commits every `FINISH_BATCH` revisions with how far it got, and a redelivered
(or duplicate) one goes on from there. A revision whose executions changed after its parts
judged it (one was ingested meanwhile) is judged again from the database, and so is every
revision after it; so are, at the end, the revisions reported during the run and those whose
executions changed after they were stored (`_catch_up`). A new re-analysis (or a new request
for one) supersedes a running one: the old one's parts and finishing step stop at their next
step.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections import defaultdict, deque
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from redline.detect.config import DetectionConfig
from redline.server.db import bulk_insert, session_scope
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
from redline.server.services.detection_config import component_config
from redline.worker.confirm_runs import settle_pending_pairs
from redline.worker.confirmation import confirm_by_history
from redline.worker.detection import judge_revision, lock_revision, store
from redline.worker.grouping import group_revision
from redline.worker.history import flagged_verdicts, summarized_series
from redline.worker.rows import Judged
from redline.worker.samples import SampleCache, Samples, ingested_executions
from sqlalchemy import Table, delete, insert, select, text, update
from sqlalchemy.dialects.postgresql import insert as upsert
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)
#: judged revisions waiting for a part's writer, at most (their verdicts are held in memory)
WRITE_AHEAD = 8
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


@dataclass(frozen=True)
class Part:
    """The series one part of a re-analysis judges: those whose id modulo ``of`` is ``index``."""

    index: int
    of: int

    def __call__(self, series_id: int) -> bool:
        return series_id % self.of == self.index


@dataclass
class Walk:
    """What a part carries from one revision to the next, so that a revision's baselines need
    nothing read back: the configuration, earlier revisions' samples, every flagged (series,
    method, revision) of its series so far, and the newest revisions with summaries, each with
    the series it has summaries of (a series with at least one finite sample), newest last."""

    config: DetectionConfig
    cache: SampleCache
    flagged: set[tuple[int, str, int]] = field(default_factory=set)
    recent: deque[tuple[int, frozenset[int]]] = field(default_factory=deque)
    #: each series' (process, counter) read so far (`redline.worker.history.judged_counters`)
    names: dict[int, tuple[str, str]] = field(default_factory=dict)

    @classmethod
    def over(cls, config: DetectionConfig) -> Walk:
        """A walk judging with ``config``, which it keeps throughout."""
        window = config.window
        return cls(config, SampleCache(window + 1), recent=deque(maxlen=window))

    def newest_first(self) -> list[tuple[int, frozenset[int]]]:
        return list(reversed(self.recent))

    def judged(
        self,
        session: Session,
        revision_id: int,
        samples: Samples,
        rows: list[dict[str, Any]],
        complete: bool,
    ) -> None:
        """``complete``: every ingested execution's samples were read; else the revision's
        series are those its summaries name, as the database sees them."""
        self.flagged.update(
            (row["series_id"], row["method"], revision_id) for row in rows if row["flagged"]
        )
        if complete:
            self._add(
                revision_id,
                frozenset(
                    series_id
                    for series_id, runs in samples.items()
                    if any(np.isfinite(run).any() for run in runs)
                ),
            )
        else:
            self._add(revision_id, summarized_series(session, revision_id))

    def kept(self, session: Session, revision_id: int) -> None:
        """A revision whose samples are gone: its stored verdicts and summaries still count."""
        self.flagged |= flagged_verdicts(session, {revision_id})
        self._add(revision_id, summarized_series(session, revision_id))

    def _add(self, revision_id: int, series: frozenset[int]) -> None:
        if series:  # a revision without summaries is no earlier revision "with samples"
            self.recent.append((revision_id, series))


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


def _current(session: Session, component_id: int, run: int, lock: bool = False) -> Reanalysis:
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


def _fail(database_url: str, component_id: int, run: int, error: BaseException) -> None:
    """The run's row must not stay "running", whatever stopped it (unless a newer run began)."""
    with session_scope(database_url) as session:
        session.execute(
            update(Reanalysis)
            .where(Reanalysis.component_id == component_id, Reanalysis.run == run)
            .values(state="failed", error=f"{type(error).__name__}: {error}", finished=utcnow())
        )


def plan(database_url: str, component_id: int, parts: int) -> int:
    """Begin a re-analysis of the component's history in ``parts`` parts; returns its run.
    Any earlier run still going is superseded, and its staged verdicts are dropped."""
    parts = max(1, parts)
    with session_scope(database_url) as session:
        session.execute(
            upsert(Reanalysis).values(component_id=component_id).on_conflict_do_nothing()
        )
        row = session.scalar(
            select(Reanalysis).where(Reanalysis.component_id == component_id).with_for_update()
        )
        assert row is not None
        revisions = revisions_with_data(session, component_id)
        row.run += 1
        row.state, row.error, row.started, row.finished = "running", "", utcnow(), None
        row.parts, row.revisions, row.parts_done = parts, revisions, []
        row.total, row.done = len(revisions) * (parts + 1), 0
        row.stored, row.from_database = 0, False
        for table in (StagedDetection, StagedRevision):
            session.execute(delete(table).where(table.component_id == component_id))
        return row.run


class _Stager(threading.Thread):
    """Stages a part's judged revisions, several in a transaction, while the part judges the
    next ones: Postgres's share of the work then runs beside the detectors, not between them."""

    def __init__(self, database_url: str, component_id: int, run: int, part: int) -> None:
        super().__init__(name=f"reanalysis-part-{part}", daemon=True)
        self.database_url, self.component_id, self.run_id, self.part = (
            database_url,
            component_id,
            run,
            part,
        )
        # (revision id, its verdicts or None: samples pruned, results kept); None: the end
        self.queue: queue.Queue[tuple[int, Judged | None] | None] = queue.Queue(WRITE_AHEAD)
        self.error: BaseException | None = None

    def run(self) -> None:
        ended = False
        while not ended:
            batch, ended = self._take()
            try:
                if self.error is None and batch:
                    self._stage(batch)
            except BaseException as exc:  # handed to the part, which raises it
                self.error = exc
            finally:
                for _ in range(len(batch) + ended):
                    self.queue.task_done()

    def _take(self) -> tuple[list[tuple[int, Judged | None]], bool]:
        """What is queued, at least one item: the judged revisions, and whether the end came."""
        items = [self.queue.get()]
        while len(items) < WRITE_AHEAD and not self.queue.empty():
            items.append(self.queue.get_nowait())
        ended = items[-1] is None
        return [item for item in items if item is not None], ended

    def _stage(self, batch: list[tuple[int, Judged | None]]) -> None:
        with session_scope(self.database_url) as session:
            # a crash loses the last staged revisions, never half of one: the redelivered part
            # stages its series again
            session.execute(text("SET LOCAL synchronous_commit TO OFF"))
            _current(session, self.component_id, self.run_id)
            owner = {"component_id": self.component_id, "run": self.run_id, "part": self.part}
            session.execute(
                insert(StagedRevision),
                [
                    {
                        **owner,
                        "revision_id": revision_id,
                        "executions": KEPT if judged is None else _joined(judged.executions),
                    }
                    for revision_id, judged in batch
                ],
            )
            rows = [{**row, **owner} for _, judged in batch if judged for row in judged.rows]
            bulk_insert(session, cast(Table, StagedDetection.__table__), rows)
            # the progress with what it counts (the row's lock last: held only until the commit)
            session.execute(
                update(Reanalysis)
                .where(Reanalysis.component_id == self.component_id, Reanalysis.run == self.run_id)
                .values(done=Reanalysis.done + len(batch))
            )

    def put(self, revision_id: int, judged: Judged | None) -> None:
        if self.error is not None:
            raise self.error
        self.queue.put((revision_id, judged))

    def finish(self) -> None:
        """Wait for every judged revision to be staged; raise the stager's error, if any."""
        self.queue.put(None)
        self.join()
        if self.error is not None:
            raise self.error


def _joined(executions: tuple[int, ...]) -> str:
    return ",".join(str(execution) for execution in executions)


def judge_part(database_url: str, component_id: int, run: int, index: int) -> bool:
    """Judge the series of part ``index`` in every planned revision, staging the verdicts.
    True when this part completed the set: the finishing step is due (`finish`)."""
    try:
        with session_scope(database_url) as session:
            row = _current(session, component_id, run, lock=True)
            if index in row.parts_done:  # delivered again after it finished: nothing to redo
                return False
            revisions, part = list(row.revisions), Part(index, row.parts)
            config = component_config(session, component_id)
            # a redelivered part starts again: what it staged, and counted, is taken back
            staged = session.scalars(
                delete(StagedRevision)
                .where(
                    StagedRevision.component_id == component_id,
                    StagedRevision.run == run,
                    StagedRevision.part == index,
                )
                .returning(StagedRevision.revision_id)
            ).all()
            session.execute(
                delete(StagedDetection).where(
                    StagedDetection.component_id == component_id,
                    StagedDetection.run == run,
                    StagedDetection.part == index,
                )
            )
            row.done -= len(staged)
        walk = Walk.over(config)
        stager = _Stager(database_url, component_id, run, index)
        stager.start()
        try:
            for revision_id in revisions:
                with session_scope(database_url) as session:
                    stager.put(revision_id, judge_revision(session, revision_id, walk, part))
        finally:
            stager.finish()
        with session_scope(database_url) as session:
            row = _current(session, component_id, run, lock=True)
            if index not in row.parts_done:
                row.parts_done = sorted([*row.parts_done, index])
            return len(row.parts_done) == row.parts
    except Superseded as exc:
        log.info("%s: part %d stops", exc, index)
        return False
    except BaseException as exc:
        _fail(database_url, component_id, run, exc)
        raise


def finish(database_url: str, component_id: int, run: int) -> bool:
    """Store the staged verdicts revision by revision in order, then settle confirmations; True
    when this call ended the re-analysis (False: superseded, or ended by another)."""
    try:
        with session_scope(database_url) as session:
            planned = list(_current(session, component_id, run).revisions)  # read once
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
            row = _current(session, component_id, run, lock=True)
            if row.state == "done":  # delivered again after its end: the charts, alerts again
                return True
            if row.state != "running":
                return False
            settle_pending_pairs(session, component_id)
            config = component_config(session, component_id)
            confirm_by_history(session, component_id, config.confirm_revisions, config.alarming)
            for table in (StagedDetection, StagedRevision):
                session.execute(delete(table).where(table.component_id == component_id))
            row.state, row.finished = "done", utcnow()
    except Superseded as exc:
        log.info("%s: its finishing step stops", exc)
        return False
    except BaseException as exc:
        _fail(database_url, component_id, run, exc)
        raise
    log.info("component %s: re-analysis %d done", component_id, run)
    return True


def _catch_up(session: Session, component_id: int, run: int, planned: list[int]) -> None:
    """What the history gained while the re-analysis ran, judged again from the database, as
    detection does: every revision from the first one that was not planned (reported during
    it) or whose ingested executions are not those its parts judged. Live detection judged
    those against earlier verdicts of the old configuration, or the finishing step stored
    verdicts whose baselines lacked an execution ingested since (a review)."""
    row = _current(session, component_id, run)
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
            or judged.get(revision_id) not in (KEPT, _joined(tuple(ingested[revision_id])))
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
    for revision_id in now[first:]:
        fresh = judge_revision(session, revision_id)
        if fresh is not None:
            store(session, session.get_one(Revision, revision_id), fresh.rows)


def _store_batch(session: Session, component_id: int, run: int, planned: list[int]) -> bool:
    """The next `FINISH_BATCH` of the ``planned`` revisions stored; False when none is left."""
    row = _current(session, component_id, run)
    start = row.stored
    batch = planned[start : start + FINISH_BATCH]
    if not batch or row.state != "running":
        return False
    # the revisions' locks before the component's, in the order detection takes them
    for revision_id in batch:
        lock_revision(session, revision_id)
    session.execute(select(Component.id).where(Component.id == component_id).with_for_update())
    row = _current(session, component_id, run, lock=True)
    if row.stored != start:
        return True  # another finishing step stored these meanwhile
    judged_from: dict[int, set[str]] = {}
    staged: dict[int, int] = defaultdict(int)  # how many parts staged each revision
    for revision_id, executions in session.execute(
        select(StagedRevision.revision_id, StagedRevision.executions).where(
            StagedRevision.component_id == component_id,
            StagedRevision.run == run,
            StagedRevision.revision_id.in_(batch),
        )
    ):
        judged_from.setdefault(revision_id, set()).add(executions)
        staged[revision_id] += 1
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
    config = component_config(session, component_id)
    fresh, stored = row.from_database, []
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
        if fresh or said != {_joined(tuple(ingested[revision_id]))}:
            # an execution was ingested (or one went) since the parts judged it: judged again
            # from what is stored now, as detection does, and so is every revision after it
            fresh = True
            judged = judge_revision(session, revision_id)
            if judged is not None:
                store(session, revision, judged.rows)
            continue
        _store_staged(session, revision, run, config.alarming, revision_id in flagged)
        stored.append(revision_id)
    if stored:
        session.execute(
            update(Revision).where(Revision.id.in_(stored)).values(analyzed_at=utcnow())
        )
    row.stored, row.done, row.from_database = start + len(batch), row.done + len(batch), fresh
    return True


def _store_staged(
    session: Session, revision: Revision, run: int, alarming: Collection[str], flagged: bool
) -> None:
    """Replace the revision's verdicts with its staged ones, by series, each series' methods in
    order (the order detection stores the flagged ones in, which grouping follows), and group
    its changes into regressions: when
    it has ``flagged`` ones, or when the verdicts replaced belonged to regressions (which may
    be left empty); otherwise grouping would find nothing to do."""
    emptied = session.scalars(
        delete(Detection)
        .where(Detection.revision_id == revision.id)
        .returning(Detection.regression_id)
    ).all()
    session.execute(
        text(
            f"INSERT INTO detection ({DETECTION_COLUMNS}) SELECT {DETECTION_COLUMNS} "
            "FROM staged_detection WHERE component_id = :component AND run = :run "
            "AND revision_id = :revision ORDER BY series_id, id"
        ),
        {"component": revision.component_id, "run": run, "revision": revision.id},
    )
    if flagged or any(regression is not None for regression in emptied):
        group_revision(session, revision, alarming)


def reanalyze_component(database_url: str, component_id: int, parts: int = 1) -> int:
    """The whole re-analysis in this process, its parts one after another (what the tasks do on
    several workers); returns how many revisions were analysed."""
    run = plan(database_url, component_id, parts)
    for index in range(parts):
        if judge_part(database_url, component_id, run, index):
            finish(database_url, component_id, run)
    with session_scope(database_url) as session:
        return len(_current(session, component_id, run).revisions)
