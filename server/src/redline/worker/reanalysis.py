"""Re-analysis of a component's whole history (after its detection configuration changed).

Idempotent: every revision with ingested results is detected again in sort-key order, each in
its own transaction (so a crash loses at most one revision's work, and running it again gives
the same result); progress (done / total) is stored in ``reanalysis`` for the API.
"""

from __future__ import annotations

import logging
import time

from redline.server.db import session_scope
from redline.server.models import Execution, Revision, utcnow
from redline.server.models_regressions import Reanalysis
from redline.worker.detection import (
    SampleCache,
    component_config,
    detect_revision,
    ingested_executions,
)
from sqlalchemy import select
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)
REANALYZE_TASK = "redline.reanalyze_component"
#: how often the stored progress (done / total) is brought up to date, at most
PROGRESS_EVERY_S = 0.5


def _progress(session: Session, component_id: int) -> Reanalysis:
    row = session.get(Reanalysis, component_id)
    if row is None:
        row = Reanalysis(component_id=component_id)
        session.add(row)
    return row


def revisions_with_data(session: Session, component_id: int) -> list[int]:
    return list(session.scalars(
        select(Revision.id).where(Revision.component_id == component_id)
        .where(select(Execution.id).where(Execution.id.in_(ingested_executions()),
                                          Execution.revision_id == Revision.id).exists())
        .order_by(Revision.order_key, Revision.id)))


def reanalyze_component(database_url: str, component_id: int) -> int:
    """Detect every revision of the component again; returns how many were analysed."""
    with session_scope(database_url) as session:
        revisions = revisions_with_data(session, component_id)
        # the history is walked in order: each revision is read once, while in a baseline
        window = component_config(session, component_id).window
        row = _progress(session, component_id)
        row.state, row.total, row.done, row.error = "running", len(revisions), 0, ""
        row.started, row.finished = utcnow(), None
    cache = SampleCache(window + 1)
    reported = time.monotonic()
    try:
        for done, revision_id in enumerate(revisions, start=1):
            detect_revision(database_url, revision_id, cache, durable=False)
            if time.monotonic() - reported >= PROGRESS_EVERY_S or done == len(revisions):
                with session_scope(database_url) as session:
                    _progress(session, component_id).done = done
                reported = time.monotonic()
    except Exception as exc:
        with session_scope(database_url) as session:
            row = _progress(session, component_id)
            row.state, row.error, row.finished = "failed", f"{type(exc).__name__}: {exc}", utcnow()
        raise
    with session_scope(database_url) as session:
        row = _progress(session, component_id)
        row.state, row.finished = "done", utcnow()
    log.info("component %s: %d revisions re-analysed", component_id, len(revisions))
    return len(revisions)
