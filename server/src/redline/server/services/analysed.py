"""Whether a revision's verdicts are those of all its ingested results: `Revision.analyzed_at`.

Whatever changes what a revision is judged from (an execution ingested, a fresh run it waited
for ending without results) clears the mark and counts up `Revision.inputs`, in its own
transaction, without the revision's detection lock. Detection reads `inputs` before it reads
the samples (`inputs_seen`), and marks the revision analysed only where `inputs` is still that
(`mark_analysed`). A result ingested while a detection judged leaves the revision unmarked, for
the detection queued after that ingestion; before, the detection under way wrote its start time
over the cleared mark, and the CI verdict read "done" without that result.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from datetime import datetime

from redline.server.models import Revision
from sqlalchemy import select, tuple_, update
from sqlalchemy.orm import Session


def _lock_in_order(session: Session, revision_ids: Collection[int]) -> None:
    """The revisions' rows locked in the order of their ids, as every caller here locks them: an
    UPDATE of several rows locks them in the order it finds them on disk, which an update moves,
    so two transactions marking overlapping revisions (two ingestions, an ingestion and a
    re-analysis's batch) could each hold a row the other waits for."""
    session.execute(
        select(Revision.id)
        .where(Revision.id.in_(revision_ids))
        .order_by(Revision.id)
        .with_for_update(key_share=True)  # FOR NO KEY UPDATE: what the UPDATE takes
    )


def unanalysed(session: Session, revision_ids: Collection[int]) -> None:
    """The revisions' verdicts no longer those of all their results: to be judged again."""
    if revision_ids:
        _lock_in_order(session, revision_ids)
        session.execute(
            update(Revision)
            .where(Revision.id.in_(revision_ids))
            .values(analyzed_at=None, inputs=Revision.inputs + 1)
        )


def inputs_seen(session: Session, revision_ids: Collection[int]) -> dict[int, int]:
    """Each revision's `Revision.inputs` as committed now, read before its samples are; a
    Core read, as the session may hold the revision's row from earlier in its transaction."""
    if not revision_ids:
        return {}
    found = session.execute(
        select(Revision.id, Revision.inputs).where(Revision.id.in_(revision_ids))
    )
    return {revision_id: inputs for revision_id, inputs in found}


def mark_analysed(session: Session, seen: Mapping[int, int], at: datetime) -> None:
    """The revisions of ``seen`` analysed at ``at``, but those whose inputs changed since
    `inputs_seen` read them: a detection queued after that change judges them again."""
    if seen:
        _lock_in_order(session, list(seen))
        session.execute(
            update(Revision)
            .where(tuple_(Revision.id, Revision.inputs).in_(list(seen.items())))
            .values(analyzed_at=at)
            .execution_options(synchronize_session=False)
        )
