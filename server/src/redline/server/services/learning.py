"""Resource-usage models of a component: requests to train one (validated here, trained by a
worker: `redline.worker.training`), the models and their files, and run-time alerts."""

from __future__ import annotations

from pathlib import Path
from urllib.parse import quote

from redline.server.models import Execution, ResourceModelRow, Revision, RuntimeAlarm
from redline.server.schemas.learning import ModelOut, ModelRequest, RuntimeAlertIn, RuntimeAlertOut
from redline.server.services.components import get_component
from redline.server.services.errors import NotFound, Unprocessable
from sqlalchemy import select
from sqlalchemy.orm import Session


def chosen_executions(session: Session, component_id: int, request: dict) -> list[Execution]:
    """The executions a request names (by revision title and by id), or the newest revision's;
    Unprocessable naming what is unknown, or when nothing is left to train on."""
    query = (
        select(Execution)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(Revision.component_id == component_id)
    )
    titles, ids = request.get("revisions") or [], request.get("executions") or []
    if not titles and not ids:
        newest = session.scalar(
            select(Revision.id)
            .join(Execution, Execution.revision_id == Revision.id)
            .where(Revision.component_id == component_id)
            .order_by(Revision.order_key.desc())
            .limit(1)
        )
        if newest is None:
            raise Unprocessable("the component has no executions to train on")
        return list(session.scalars(query.where(Execution.revision_id == newest)))
    found = list(
        session.scalars(
            query.where((Revision.title.in_(titles)) | (Execution.id.in_(ids))).order_by(
                Execution.id
            )
        )
    )
    known_titles = set(
        session.scalars(
            select(Revision.title).where(
                Revision.component_id == component_id, Revision.title.in_(titles)
            )
        )
    )
    missing = [t for t in titles if t not in known_titles]
    missing_ids = sorted(set(ids) - {e.id for e in found})
    if missing or missing_ids:
        raise Unprocessable(
            "unknown "
            + "; ".join(
                part
                for part in (
                    f"revisions {missing}" if missing else "",
                    f"executions {missing_ids} (of this component)" if missing_ids else "",
                )
                if part
            )
        )
    usable = [e for e in found if e.pruned_at is None]
    if not usable:
        raise Unprocessable("the recordings of these executions were pruned (retention)")
    return usable


def request_model(session: Session, name: str, data: ModelRequest) -> ResourceModelRow:
    component = get_component(session, name)
    request = data.model_dump()
    chosen_executions(session, component.id, request)  # refuse now what the worker would
    row = ResourceModelRow(component_id=component.id, request=request)
    session.add(row)
    session.commit()
    return row


def model_out(row: ResourceModelRow, component: str) -> ModelOut:
    return ModelOut(
        id=row.id,
        component=component,
        state=row.state,
        error=row.error,
        request=row.request,
        process=row.process,
        metrics=row.metrics,
        provenance=row.provenance,
        created=row.created,
        finished=row.finished,
        file=f"/api/v1/components/{quote(component)}/models/{row.id}/file"
        if row.state == "done"
        else None,
    )


def list_models(session: Session, name: str) -> list[ModelOut]:
    component = get_component(session, name)
    rows = session.scalars(
        select(ResourceModelRow)
        .where(ResourceModelRow.component_id == component.id)
        .order_by(ResourceModelRow.id.desc())
    )
    return [model_out(row, component.name) for row in rows]


def get_model(session: Session, name: str, ident: int) -> ResourceModelRow:
    component = get_component(session, name)
    row = session.get(ResourceModelRow, ident)
    if row is None or row.component_id != component.id:
        raise NotFound(f"component {name!r} has no model {ident}")
    return row


def model_file(session: Session, name: str, ident: int) -> Path:
    row = get_model(session, name, ident)
    if row.state != "done" or not row.path or not Path(row.path).exists():
        raise NotFound(f"model {ident} has no file ({row.state})")
    return Path(row.path)


def record_alert(session: Session, name: str, data: RuntimeAlertIn) -> RuntimeAlertOut:
    component = get_component(session, name)
    if data.model is not None:
        get_model(session, name, data.model)
    row = RuntimeAlarm(
        component_id=component.id,
        model_id=data.model,
        host=data.host,
        process=data.process,
        target=data.target,
        started=data.started,
        residual=data.residual,
        threshold=data.threshold,
        step=data.step,
    )
    session.add(row)
    session.commit()
    return alert_out(row)


def alert_out(row: RuntimeAlarm) -> RuntimeAlertOut:
    return RuntimeAlertOut(
        id=row.id,
        target=row.target,
        started=row.started,
        residual=row.residual,
        threshold=row.threshold,
        step=row.step,
        model=row.model_id,
        host=row.host,
        process=row.process,
        at=row.at,
    )


def list_alerts(session: Session, name: str, limit: int) -> list[RuntimeAlertOut]:
    component = get_component(session, name)
    rows = session.scalars(
        select(RuntimeAlarm)
        .where(RuntimeAlarm.component_id == component.id)
        .order_by(RuntimeAlarm.id.desc())
        .limit(limit)
    )
    return [alert_out(row) for row in rows]
