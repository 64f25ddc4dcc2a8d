"""Judging onward: a revision's new results, then the later revisions they are a baseline of.

A revision's verdicts depend on the revisions before it: their samples pool into its baseline,
and under ``recent`` their flagged verdicts restart it (`redline.worker.baselines`). Results that
arrive late — an agent slower than the others, a job leased again after its host was lost, an
import — change what the later revisions should have been judged against. Judging only the
next revision again left the others with verdicts that depended on the order in which results
happened to arrive (a trial with four agents saw it); here the later revisions are judged again,
oldest first, as if the results had come in order:

- at least the ``2 x window`` revisions with results after it (its samples may be in their
  baselines, which reach past revisions the host was busy in: `redline.detect.baseline.lookback`;
  one for ``previous``, or ``pinned`` unless it is the pinned revision, when every later one
  is: the next one always reads what it measured, to say what is no longer measured);
- then on while anything a later revision reads came out different — a flagged or "not enough
  data" verdict (a step may be found there), or a step found at an earlier revision — until
  as many revisions in a row come out unchanged;
- for a confirmation run (in no baseline), the later revisions only if the confirmed revision's
  verdicts changed.

Walks of one component take turns (a transaction-scoped advisory lock held by a connection of
its own for the walk, which also holds under PgBouncer's transaction pooling; a waiting walk
holds no connection), so two late arrivals judged at once still end as in order: the later walk
reads what the earlier stored.

Known limits, where stored results can still differ from judging in order: a later revision
that lacks a series, or follows revisions the host was busy in throughout
(`redline.detect.baseline.lookback`), reaches further back for it than ``window`` revisions with
results, and one
beyond the walk is not judged again unless a changed verdict carries the walk to it; a step
found (`redline.worker.detection`) at a revision before the late one, by a revision judged
without it, stays stored; confirmation by history is settled as verdicts come and is not
undone; a regression's range is made again from its changes' spans as they are judged again
(`redline.worker.grouping._fit`), but two changes it gathered are not split into two
regressions when they no longer overlap. A re-analysis of the component judges everything
again.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager

from redline.detect.result import NOT_ENOUGH_DATA
from redline.server.db import get_engine, session_scope
from redline.server.models import Detection, Revision
from redline.server.services.detection_config import component_config
from redline.server.services.reach import later_with_results, reach
from redline.worker.detection import detect_and_store
from sqlalchemy import func, select
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)
#: the first key of the advisory lock a component's walk holds
WALK_LOCK = 0x524F  # "RO"
#: how often a walk waiting for its turn tries again
TURN_POLL_S = 0.2

Fingerprint = frozenset[tuple[int, str, bool, bool]]


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
    connection of its own (the walk's detections commit on others). A walk waiting for its
    turn holds no connection between tries: under PgBouncer a waiter holding a server
    connection could starve the walk it waits for of one."""
    engine = get_engine(database_url)
    while True:
        with engine.connect() as connection, connection.begin():
            if connection.scalar(select(func.pg_try_advisory_xact_lock(WALK_LOCK, component_id))):
                yield
                return
        time.sleep(TURN_POLL_S)


def _judge(database_url: str, revision_id: int) -> bool:
    """Judge and store the revision: whether anything a later revision reads changed (its
    flagged or undecided verdicts, or a step found at an earlier revision)."""
    with session_scope(database_url) as session:
        before = fingerprint(session, revision_id)
    judged = detect_and_store(database_url, revision_id)
    if judged is None:
        return False
    if any(row["revision_id"] != revision_id for row in judged.rows):
        return True
    with session_scope(database_url) as session:
        return fingerprint(session, revision_id) != before


def judge_onward(
    database_url: str,
    revision_id: int,
    also: Iterable[int] = (),
    confirmation: bool = False,
    told: Callable[[int], object] | None = None,
) -> list[int]:
    """Judge ``revision_id``, then the later revisions its results reach, oldest first (the
    module's rules), and every later revision of ``also`` (waiting for it) on the way.

    ``confirmation``: its new results are a confirmation run's, in no baseline: the later
    revisions are judged only if its own verdicts changed. ``told`` is called with each
    revision as soon as it is judged (its alerts and commit status need not wait for the
    walk). Returns the ids judged, in order. Each revision is judged and stored in a
    transaction of its own (`detect_and_store`); a walk interrupted (a worker lost) is done
    again whole.
    """
    with session_scope(database_url) as session:
        revision = session.get(Revision, revision_id)
        if revision is None:
            return []
        component_id = revision.component_id
    judged: list[int] = []
    with taking_turns(database_url, component_id):
        with session_scope(database_url) as session:
            revision = session.get_one(Revision, revision_id)
            depth = reach(component_config(session, component_id), revision)
            later = later_with_results(session, revision, None)
            waiting = set(also) & set(later)
        moved = _judge(database_url, revision_id)
        judged.append(revision_id)
        if told is not None:
            told(revision_id)
        if confirmation and not moved:
            depth = 0
        unchanged = 0
        for later_id in later:
            if not waiting and depth is not None and unchanged >= depth:
                break
            unchanged = 0 if _judge(database_url, later_id) else unchanged + 1
            judged.append(later_id)
            waiting.discard(later_id)
            if told is not None:
                told(later_id)
    if len(judged) > 1:
        log.info("revision %s judged, then %d later ones", revision_id, len(judged) - 1)
    return judged
