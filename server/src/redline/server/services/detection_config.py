"""A component's detection configuration, and the re-analysis of its history after a change."""

from __future__ import annotations

import hashlib
import json
import logging
from typing import Any

from redline.detect.config import ConfigError, DetectionConfig
from redline.detect.count_rate import CountRate
from redline.server.models import Component, DetectionConfigRow, JudgingConfig, Reanalysis, utcnow
from redline.server.schemas.regressions import DetectionConfigIn, DetectionConfigOut, ReanalysisOut
from redline.server.services.components import get_component
from redline.server.services.errors import BadRequest
from sqlalchemy import select
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


def judging_config_id(session: Session, component_id: int, config: DetectionConfig) -> int:
    """The id of the `JudgingConfig` row of ``config`` for the component, made the first time a
    verdict is judged by it: its fields, and each method's parameters as it judges (the count
    method, which every component's rare events are judged by, included)."""
    params = {d.name: d.params_as_judged() for d in config.detectors()}
    params[CountRate.name] = CountRate().get_params()
    kept = {"config": config.as_dict(), "params": params}
    digest = hashlib.sha256(json.dumps(kept, sort_keys=True).encode()).hexdigest()
    session.execute(
        insert(JudgingConfig)
        .values(component_id=component_id, digest=digest, created=utcnow(), **kept)
        .on_conflict_do_nothing(index_elements=["component_id", "digest"])
    )
    return session.scalars(
        select(JudgingConfig.id).where(
            JudgingConfig.component_id == component_id, JudgingConfig.digest == digest
        )
    ).one()


def judged_params(session: Session, config_id: int | None, method: str) -> dict[str, Any] | None:
    """``method``'s parameters as they judged under the kept configuration ``config_id``; None
    when it is not known (a verdict judged before configurations were kept)."""
    row = session.get(JudgingConfig, config_id) if config_id is not None else None
    return dict(row.params[method]) if row is not None and method in row.params else None


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
