"""Which revisions read a revision's results: the later ones whose baselines may hold it.

Ingestion and imports mark those not yet analysed with the revision itself
(`redline.server.services.analysed`), and a walk judges them again in order
(`redline.worker.onward`).
"""

from __future__ import annotations

from redline.detect.baseline import lookback
from redline.detect.config import DetectionConfig
from redline.server.models import Execution, Job, JobState, Revision, revision_place
from redline.server.services.detection_config import component_config
from sqlalchemy import Select, select
from sqlalchemy.orm import Session


def ingested_executions() -> Select[int]:
    """A revision's own executions whose ingestion finished (their job is done), whatever
    series they hold: a recording whose every sample was NaN has no summary rows but must still
    be judged. Confirmation runs (`redline.worker.confirm_runs`) are judged apart, in pairs."""
    return (
        select(Execution.id)
        .join(Job, Job.id == Execution.job_id)
        .where(Job.state == JobState.done, Job.pair == 0)
    )


def reach(config: DetectionConfig, revision: Revision) -> int | None:
    """How many later revisions with results read ``revision`` (None: all of them): those whose
    baselines may hold it, reaching past revisions the host was busy in
    (`redline.detect.baseline.lookback`); at least the next, which says what it no longer
    measures."""
    if config.baseline == "pinned":
        return None if revision.title == config.pinned else 1
    return 1 if config.baseline == "previous" else lookback(config.window)


def later_with_results(session: Session, revision: Revision, limit: int | None) -> list[int]:
    """The ids of the later revisions of the component with ingested results whose samples are
    kept (a pruned revision keeps its verdicts), oldest first."""
    query = (
        select(Revision.id)
        .where(
            Revision.component_id == revision.component_id,
            revision_place() > revision.place,
            select(Execution.id)
            .where(
                Execution.revision_id == Revision.id,
                Execution.id.in_(ingested_executions()),
                Execution.pruned_at.is_(None),
            )
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
