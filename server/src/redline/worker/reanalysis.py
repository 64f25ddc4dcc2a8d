"""Re-analysis of a component's whole history (after its detection configuration changed).

Idempotent: every revision with ingested results is detected again in sort-key order, each
stored in its own transaction (so a crash loses at most a few revisions' work, and running it
again gives the same result); progress (done / total) is stored in ``reanalysis`` for the API.
Judging and storing overlap: a writer thread stores revision n while revision n + 1 is judged.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from redline.server.db import session_scope
from redline.server.models import Execution, Reanalysis, Revision, utcnow
from redline.server.services.detection_config import component_config
from redline.worker.detection import judge_revision, store_judged
from redline.worker.history import (
    flagged_verdicts,
    ingested_fingerprint,
    summarized_series,
)
from redline.worker.rows import Judged
from redline.worker.samples import SampleCache, Samples, ingested_executions
from sqlalchemy import select
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)
#: how often the stored progress (done / total) is brought up to date, at most
PROGRESS_EVERY_S = 0.5
#: judged revisions waiting for the writer, at most (their verdicts are held in memory)
WRITE_AHEAD = 4
KEPT = "kept"  # a revision whose samples are gone: its stored results stand


@dataclass
class Walk:
    """What a re-analysis carries from one revision to the next, so that a revision's baselines
    need nothing read back: earlier revisions' samples, every flagged (series, method,
    revision) so far, and the newest revisions with summaries, each with the series it has
    summaries of (a series with at least one finite sample), newest last.

    Valid only while the history stays as it was when the walk began (``fingerprint``) and the
    configuration's window is the walk's: otherwise ``usable`` turns False for good, and the
    revisions left are judged from the database as `detect_revision` judges them.
    """

    cache: SampleCache
    window: int
    fingerprint: tuple[int, int]
    flagged: set[tuple[int, str, int]] = field(default_factory=set)
    recent: deque[tuple[int, frozenset[int]]] = field(default_factory=deque)
    usable: bool = True
    #: called once when the walk turns unusable, before anything is read from the database
    #: (a re-analysis waits there until every revision judged so far is stored)
    on_disable: Callable[[], None] | None = None

    @classmethod
    def over(cls, window: int, fingerprint: tuple[int, int]) -> Walk:
        return cls(SampleCache(window + 1), window, fingerprint, recent=deque(maxlen=window))

    def check(self, session: Session, component_id: int) -> None:
        """Stop using the memory if executions were ingested since the walk began."""
        if self.usable and ingested_fingerprint(session, component_id) != self.fingerprint:
            self.disable(f"component {component_id}: executions ingested during the re-analysis")

    def disable(self, why: str) -> None:
        log.info("%s; the rest of the re-analysis reads its baselines from the database", why)
        self.usable = False
        if self.on_disable is not None:
            self.on_disable()

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


def _progress(session: Session, component_id: int) -> Reanalysis:
    row = session.get(Reanalysis, component_id)
    if row is None:
        row = Reanalysis(component_id=component_id)
        session.add(row)
    return row


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


class _Writer(threading.Thread):
    """Stores judged revisions in order, in its own transactions, while the walk judges the
    next ones: Postgres's share of the work (300 rows a revision of 100 series, with their keys
    and indexes) then runs on the other core instead of between two revisions' detections."""

    def __init__(self, database_url: str, component_id: int) -> None:
        super().__init__(name="reanalysis-writer", daemon=True)
        self.database_url, self.component_id = database_url, component_id
        # a Judged to store; KEPT: a revision whose stored results stand; None: the end
        self.queue: queue.Queue[Judged | str | None] = queue.Queue(maxsize=WRITE_AHEAD)
        self.done = 0
        self.error: BaseException | None = None

    def run(self) -> None:
        reported = time.monotonic()
        while True:
            judged = self.queue.get()
            try:
                if judged is None:
                    return
                if self.error is not None:
                    continue  # emptying the queue: the walk stops at its next put
                if judged is not KEPT:
                    assert isinstance(judged, Judged)
                    store_judged(self.database_url, judged, durable=False)
                self.done += 1
                if time.monotonic() - reported >= PROGRESS_EVERY_S:
                    self._report()
                    reported = time.monotonic()
            except BaseException as exc:  # handed to the walk, which raises it
                self.error = exc
            finally:
                self.queue.task_done()

    def _report(self) -> None:
        with session_scope(self.database_url) as session:
            _progress(session, self.component_id).done = self.done

    def put(self, judged: Judged | str) -> None:
        if self.error is not None:
            raise self.error
        self.queue.put(judged)

    def drain(self) -> None:
        """Wait until every revision handed over so far is stored."""
        self.queue.join()
        if self.error is not None:
            raise self.error

    def finish(self) -> None:
        """Wait for every judged revision to be stored; raise the writer's error, if any."""
        self.queue.put(None)
        self.join()
        self._report()
        if self.error is not None:
            raise self.error


def _walk(database_url: str, revisions: list[int], walk: Walk, writer: _Writer) -> None:
    """Judge the revisions in order, handing each to the writer; what a revision's baselines
    need of the earlier ones is carried along in memory (`Walk`) while it stays valid."""
    walk.on_disable = writer.drain  # the database must hold every earlier verdict first
    for revision_id in revisions:
        with session_scope(database_url) as session:
            judged = judge_revision(session, revision_id, walk)
        writer.put(KEPT if judged is None else judged)  # None: samples pruned, results kept


def reanalyze_component(database_url: str, component_id: int) -> int:
    """Detect every revision of the component again; returns how many were analysed."""
    with session_scope(database_url) as session:
        revisions = revisions_with_data(session, component_id)
        walk = Walk.over(
            component_config(session, component_id).window,
            ingested_fingerprint(session, component_id),
        )
        row = _progress(session, component_id)
        row.state, row.total, row.done, row.error = "running", len(revisions), 0, ""
        row.started, row.finished = utcnow(), None
    writer = _Writer(database_url, component_id)
    writer.start()
    try:
        try:
            _walk(database_url, revisions, walk, writer)
        finally:
            writer.finish()  # stores what was judged; raises the writer's own error
    except BaseException as exc:  # the row must not stay "running", whatever stopped it
        with session_scope(database_url) as session:
            row = _progress(session, component_id)
            row.state, row.error, row.finished = "failed", f"{type(exc).__name__}: {exc}", utcnow()
        raise
    with session_scope(database_url) as session:
        row = _progress(session, component_id)
        row.state, row.finished = "done", utcnow()
    log.info("component %s: %d revisions re-analysed", component_id, len(revisions))
    return len(revisions)
