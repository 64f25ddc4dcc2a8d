"""A component's detection configuration, and the re-analysis of its history after a change."""

from __future__ import annotations

import logging
from typing import Any

from redline.detect.config import ConfigError, DetectionConfig
from redline.server.models import Component, DetectionConfigRow, Reanalysis, utcnow
from redline.server.schemas.regressions import DetectionConfigIn, DetectionConfigOut, ReanalysisOut
from redline.server.services.components import get_component
from redline.server.services.errors import BadRequest
from sqlalchemy.dialects.postgresql import insert
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)


def component_config(session: Session, component_id: int) -> DetectionConfig:
    """The stored configuration, or the defaults (also when the stored one no longer parses,
    which is logged): what the worker judges by and the pages and API say."""
    row = session.get(DetectionConfigRow, component_id)
    try:
        return DetectionConfig.parse(row.config if row else None)
    except ConfigError as exc:
        log.error(
            "component %s: stored detection configuration unusable (%s); defaults used",
            component_id,
            exc,
        )
        return DetectionConfig()


def get_config(session: Session, component_name: str) -> DetectionConfigOut:
    component = get_component(session, component_name)
    return DetectionConfigOut(**component_config(session, component.id).as_dict())


def set_config(session: Session, component_name: str, data: DetectionConfigIn) -> Component:
    """Validate and store the configuration (a field left out takes its default); BadRequest
    names the field at fault."""
    component = get_component(session, component_name)
    _store(session, component, data.model_dump(exclude={"reanalyze"}))
    return component


def patch_config(session: Session, component_name: str, data: DetectionConfigIn) -> Component:
    """Change only the fields given, over the stored configuration (a trial's one-field `PUT`
    reset the rest: the demo's alarm method and pairs); ``thresholds`` merge per method, one
    parameter at a time. Validated as a whole; BadRequest names the field at fault."""
    component = get_component(session, component_name)
    merged = component_config(session, component.id).as_dict()
    given = data.model_dump(exclude_unset=True, exclude={"reanalyze"})
    for method, params in given.pop("thresholds", {}).items():
        merged["thresholds"][method] = {**merged["thresholds"].get(method, {}), **params}
    _store(session, component, {**merged, **given})
    return component


def _store(session: Session, component: Component, fields: dict[str, Any]) -> None:
    try:
        config = DetectionConfig.parse(fields)
    except ConfigError as exc:
        raise BadRequest(f"detection configuration: {exc}") from None
    stored = dict(config=config.as_dict(), updated=utcnow())
    session.execute(
        insert(DetectionConfigRow)
        .values(component_id=component.id, **stored)
        .on_conflict_do_update(index_elements=["component_id"], set_=stored)
    )
    session.commit()


def request_reanalysis(session: Session, component: Component) -> None:
    """Mark a re-analysis queued (replacing the last one's progress); the caller sends the task."""
    queued = dict(
        state="queued", total=0, done=0, error="", requested=utcnow(), started=None, finished=None
    )
    session.execute(
        insert(Reanalysis)
        .values(component_id=component.id, **queued)
        .on_conflict_do_update(
            index_elements=["component_id"],
            # a run still going is superseded at once: its parts stop at their next step
            set_={**queued, "run": Reanalysis.__table__.c.run + 1},
        )
    )
    session.commit()


def reanalysis_status(session: Session, component_name: str) -> ReanalysisOut:
    component = get_component(session, component_name)
    row = session.get(Reanalysis, component.id)
    if row is None:
        return ReanalysisOut(
            component=component.name,
            state="none",
            total=0,
            done=0,
            error="",
            requested=None,
            started=None,
            finished=None,
        )
    return ReanalysisOut(
        component=component.name,
        state=row.state,
        total=row.total,
        done=row.done,
        revisions=len(row.revisions),
        parts=row.parts,
        error=row.error,
        requested=row.requested,
        started=row.started,
        finished=row.finished,
    )
