"""Re-analysis of a component's whole history (after its detection configuration changed), split
by series across workers.

A series is judged against its own history alone, so a re-analysis fans out by series: `plan`
records the revisions to judge and how many parts share the series; each part (`judge_part`, a
task of its own on any worker) walks every planned revision in sort-key order and judges the
series whose id, modulo the parts, is its index, carrying what the baselines need of the earlier
revisions in memory (`Walk`), and stages its verdicts (`StagedDetection`, and a `StagedRevision`
naming the executions each revision was judged from). The part that completes the set queues the
finishing step (Postgres decides which, under the re-analysis row's lock: a Celery chord would
need a result backend, which Redline does without): `redline.worker.reanalysis_finish` stores
the staged verdicts in revision order, as detection would have (tested).

Idempotent and resumable: a part delivered again after its worker died stages its series again
(its progress taken back first: ``done`` counts what is staged and stored, in the same
transactions); one delivered again after it finished does nothing. A new re-analysis (or a new
request for one) supersedes a running one: the old one's parts stop at their next step.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections import deque
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from redline.detect.baseline import lookback
from redline.detect.config import DetectionConfig
from redline.detect.result import NOT_ENOUGH_DATA
from redline.recording import SeriesKey
from redline.server.db import bulk_insert, session_scope
from redline.server.models import Reanalysis, StagedDetection, StagedRevision, utcnow
from redline.server.services.analysed import inputs_seen
from redline.server.services.detection_config import component_config
from redline.worker.detection import judge_revision
from redline.worker.history import flagged_verdicts, summarized_series
from redline.worker.reanalysis_finish import (
    KEPT,
    TRANSIENT,
    Superseded,
    current_run,
    fail_run,
    finish,
    joined,
    revisions_with_data,
    run_config,
)
from redline.worker.rows import Judged
from redline.worker.samples import SampleCache, Samples
from sqlalchemy import Table, delete, insert, select, text, update
from sqlalchemy.dialects.postgresql import insert as upsert
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)
#: judged revisions waiting for a part's writer, at most (their verdicts are held in memory)
WRITE_AHEAD = 8


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
    #: every (series, method, revision) judged "not enough data" so far: a step may be found
    #: there later (`redline.worker.baselines.Baselines.step`)
    undecided: set[tuple[int, str, int]] = field(default_factory=set)
    recent: deque[tuple[int, frozenset[int]]] = field(default_factory=deque)
    #: each series' names read so far (`redline.worker.history.judged_counters`)
    names: dict[int, SeriesKey] = field(default_factory=dict)

    @classmethod
    def over(cls, config: DetectionConfig) -> Walk:
        """A walk judging with ``config``, which it keeps throughout."""
        depth = lookback(config.window)
        return cls(config, SampleCache(depth + 1), recent=deque(maxlen=depth))

    def newest_first(self) -> list[tuple[int, frozenset[int]]]:
        return list(reversed(self.recent))

    def judged(
        self,
        session: Session,
        revision_id: int,
        samples: Samples,
        rows: list[dict[str, Any]],
        complete: bool,
        busy: Collection[int] = (),
    ) -> None:
        """``complete``: every ingested execution's samples were read; else the revision's
        series are those its summaries name, as the database sees them. ``busy``: the series
        only runs measured while the host was busy have (no values, but summaries: they count
        among the revisions a baseline looks through, as the database counts them). ``rows``
        may hold the verdict of an earlier revision a step was found at, which its baselines
        then start at."""
        for row in rows:
            key = (row["series_id"], row["method"], row["revision_id"])
            if row["flagged"]:
                self.flagged.add(key)
                self.undecided.discard(key)
            elif row["verdict"] == NOT_ENOUGH_DATA:
                self.undecided.add(key)
        if complete:
            self._add(
                revision_id,
                frozenset(
                    series_id
                    for series_id, runs in samples.items()
                    if any(np.isfinite(run).any() for run in runs)
                )
                | frozenset(busy),
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
        row.config = component_config(session, component_id).as_dict()
        for table in (StagedDetection, StagedRevision):
            session.execute(delete(table).where(table.component_id == component_id))
        return row.run


class _Stager(threading.Thread):
    """Stages a part's judged revisions, several in a transaction, while the part judges the
    next ones: Postgres's share of the work then runs beside the detectors, not between them."""

    def __init__(
        self, database_url: str, component_id: int, run: int, part: int, seen: dict[int, int]
    ) -> None:
        super().__init__(name=f"reanalysis-part-{part}", daemon=True)
        self.database_url, self.component_id, self.run_id, self.part = (
            database_url,
            component_id,
            run,
            part,
        )
        self.seen = seen  # the revisions' inputs when the part began (`analysed.inputs_seen`)
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
            current_run(session, self.component_id, self.run_id)
            owner = {"component_id": self.component_id, "run": self.run_id, "part": self.part}
            session.execute(
                insert(StagedRevision),
                [
                    {
                        **owner,
                        "revision_id": revision_id,
                        "executions": KEPT if judged is None else joined(judged.executions),
                        "inputs": self.seen.get(revision_id),
                    }
                    for revision_id, judged in batch
                ],
            )
            # a judged revision's own verdicts, and those of earlier revisions a step was found
            # at (which may be in this batch too: they replace what it staged of them)
            own: list[dict[str, Any]] = []
            steps: list[dict[str, Any]] = []
            for _, judged in batch:
                if judged is None:
                    continue
                for row in judged.rows:
                    mine = row["revision_id"] == judged.revision_id
                    (own if mine else steps).append({**row, **owner})
            bulk_insert(session, cast(Table, StagedDetection.__table__), own)
            self._stage_steps(session, steps)
            # the progress with what it counts (the row's lock last: held only until the commit)
            session.execute(
                update(Reanalysis)
                .where(Reanalysis.component_id == self.component_id, Reanalysis.run == self.run_id)
                .values(done=Reanalysis.done + len(batch))
            )

    def _stage_steps(self, session: Session, rows: list[dict[str, Any]]) -> None:
        """Verdicts of earlier revisions a step was found at (`redline.worker.detection`), each
        replacing what this part staged of that revision, series and method: the finishing
        step stores them with that revision, as detection would have left it."""
        for row in rows:
            session.execute(
                delete(StagedDetection).where(
                    StagedDetection.component_id == self.component_id,
                    StagedDetection.run == self.run_id,
                    StagedDetection.part == self.part,
                    StagedDetection.revision_id == row["revision_id"],
                    StagedDetection.series_id == row["series_id"],
                    StagedDetection.method == row["method"],
                )
            )
        bulk_insert(session, cast(Table, StagedDetection.__table__), rows)

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

    def abandon(self) -> None:
        """Let the thread end after what it holds (the part failed: its own error stands)."""
        self.queue.put(None)
        self.join()


def judge_part(database_url: str, component_id: int, run: int, index: int) -> bool:
    """Judge the series of part ``index`` in every planned revision, staging the verdicts.
    True when this part completed the set: the finishing step is due
    (`redline.worker.reanalysis_finish.finish`)."""
    try:
        with session_scope(database_url) as session:
            row = current_run(session, component_id, run, lock=True)
            if index in row.parts_done:  # delivered again after it finished: nothing to redo,
                # but the finishing step is due again if queueing it failed (a broker outage)
                return len(row.parts_done) == row.parts and row.state == "running"
            revisions, part = list(row.revisions), Part(index, row.parts)
            # before any sample is read: the finishing step judges again from the database
            # every revision whose inputs changed since (its own runs, or a baseline's)
            seen = inputs_seen(session, revisions)
            config = run_config(session, row)
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
        stager = _Stager(database_url, component_id, run, index, seen)
        stager.start()
        try:
            for revision_id in revisions:
                with session_scope(database_url) as session:
                    judged = judge_revision(session, revision_id, walk, part)
                stager.put(revision_id, judged)  # outside the transaction: a wait, not a lock
        except BaseException:
            stager.abandon()
            raise
        stager.finish()
        with session_scope(database_url) as session:
            row = current_run(session, component_id, run, lock=True)
            if index not in row.parts_done:
                row.parts_done = sorted([*row.parts_done, index])
            return len(row.parts_done) == row.parts
    except Superseded as exc:
        log.info("%s: part %d stops", exc, index)
        return False
    except TRANSIENT:
        raise  # the task tries the part again, which takes back what it staged
    except BaseException as exc:
        fail_run(database_url, component_id, run, exc)
        raise


def reanalyze_component(database_url: str, component_id: int, parts: int = 1) -> int:
    """The whole re-analysis in this process, its parts one after another (what the tasks do on
    several workers); returns how many revisions were analysed."""
    run = plan(database_url, component_id, parts)
    for index in range(parts):
        if judge_part(database_url, component_id, run, index):
            finish(database_url, component_id, run)
    with session_scope(database_url) as session:
        return len(current_run(session, component_id, run).revisions)
