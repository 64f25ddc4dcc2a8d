"""Judging onward: a revision's new results, then the later revisions they are a baseline of.

A revision's verdicts depend on the revisions before it: their samples pool into its baseline,
and under ``recent`` their flagged verdicts restart it (`redline.worker.baselines`). Results that
arrive late — an agent slower than the others, a job leased again after its host was lost, an
import — change what the later revisions should have been judged against. Judging only the
next revision again left the others with verdicts that depended on the order in which results
happened to arrive (a trial with four agents saw it); here the later revisions are judged again,
oldest first, as if the results had come in order:

- at least the ``window`` revisions with results after it (its samples are in their baselines;
  one for ``previous``; under ``pinned``, every later one when it is the pinned revision);
- then on while any verdict a later revision reads (flagged, or "not enough data": a step may be
  found there) came out different, until ``window`` revisions in a row come out unchanged.

Walks of one component take turns (a transaction-scoped advisory lock held by a connection of
its own for the walk, which also holds under PgBouncer's transaction pooling), so two late
arrivals judged at once still end as in order: the later walk reads what the earlier stored.
Known limit: a later revision that lacks a series reaches further back for it than ``window``
revisions with results; such a revision beyond the reach is not judged again unless a verdict
change carries the walk to it.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from contextlib import contextmanager

from redline.detect.config import DetectionConfig
from redline.detect.result import NOT_ENOUGH_DATA
from redline.server.db import get_engine, session_scope
from redline.server.models import Detection, Execution, Revision
from redline.server.services.detection_config import component_config
from redline.worker.detection import detect_revision
from redline.worker.samples import ingested_executions
from sqlalchemy import func, select, tuple_
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)
#: the first key of the advisory lock a component's walk holds
WALK_LOCK = 0x524F  # "RO"

Fingerprint = frozenset[tuple[int, str, bool, bool]]


def reach(config: DetectionConfig, revision: Revision) -> int | None:
    """How many later revisions with results hold ``revision`` in their baselines (None: all)."""
    if config.baseline == "pinned":
        return None if revision.title == config.pinned else 0
    return 1 if config.baseline == "previous" else config.window


def later_with_results(session: Session, revision: Revision, limit: int | None) -> list[int]:
    """The ids of the later revisions of the component with ingested results, oldest first."""
    query = (
        select(Revision.id)
        .where(
            Revision.component_id == revision.component_id,
            tuple_(Revision.order_key, Revision.id) > (revision.order_key, revision.id),
            select(Execution.id)
            .where(Execution.revision_id == Revision.id, Execution.id.in_(ingested_executions()))
            .exists(),
        )
        .order_by(Revision.order_key, Revision.id)
    )
    return list(session.scalars(query if limit is None else query.limit(limit)))


def in_reach(session: Session, revision_id: int) -> list[int]:
    """The later revisions a walk from ``revision_id`` judges again at least (`reach`)."""
    revision = session.get_one(Revision, revision_id)
    return later_with_results(
        session, revision, reach(component_config(session, revision.component_id), revision)
    )


def fingerprint(session: Session, revision_id: int) -> Fingerprint:
    """What the later revisions read of this one's verdicts: per series and method, whether
    flagged, whether undecided."""
    rows = session.execute(
        select(Detection.series_id, Detection.method, Detection.flagged, Detection.verdict).where(
            Detection.revision_id == revision_id
        )
    )
    return frozenset(
        (series, method, bool(flagged), verdict == NOT_ENOUGH_DATA)
        for series, method, flagged, verdict in rows
    )


@contextmanager
def taking_turns(database_url: str, component_id: int) -> Iterator[None]:
    """One walk of the component at a time: a lock held, for the walk, by a transaction on a
    connection of its own (the walk's detections commit on others)."""
    with get_engine(database_url).connect() as connection, connection.begin():
        connection.execute(select(func.pg_advisory_xact_lock(WALK_LOCK, component_id)))
        yield


def judge_onward(database_url: str, revision_id: int, also: Iterable[int] = ()) -> list[int]:
    """Judge ``revision_id``, then the later revisions its results reach, oldest first (the
    module's rules), and every revision of ``also`` (later revisions waiting for it) on the way.

    Returns the ids judged, in order. Each revision is judged and stored in a transaction of its
    own (`detect_revision`); a walk interrupted (a worker lost) is done again whole.
    """
    with session_scope(database_url) as session:
        revision = session.get(Revision, revision_id)
        if revision is None:
            return []
        component_id = revision.component_id
    with taking_turns(database_url, component_id):
        with session_scope(database_url) as session:
            revision = session.get_one(Revision, revision_id)
            config = component_config(session, component_id)
            depth = reach(config, revision)
            later = later_with_results(session, revision, None)
            waiting = set(also) - {revision_id}
        detect_revision(database_url, revision_id)
        judged, unchanged = [revision_id], 0
        for later_id in later:
            if not waiting and depth is not None and unchanged >= depth:
                break
            with session_scope(database_url) as session:
                before = fingerprint(session, later_id)
            detect_revision(database_url, later_id)
            with session_scope(database_url) as session:
                after = fingerprint(session, later_id)
            judged.append(later_id)
            waiting.discard(later_id)
            unchanged = unchanged + 1 if before == after else 0
    if len(judged) > 1:
        log.info("revision %s judged, then %d later ones", revision_id, len(judged) - 1)
    return judged
