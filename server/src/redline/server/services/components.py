"""Components: the things whose revisions are measured."""

from __future__ import annotations

from redline.server.models import Component
from redline.server.schemas import ComponentCreate
from redline.server.services.errors import Conflict, NotFound
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session


def create_component(session: Session, data: ComponentCreate) -> Component:
    component = Component(**data.model_dump())
    session.add(component)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        raise Conflict(f"component {data.name!r} already exists") from None
    return component


def list_components(session: Session) -> list[Component]:
    return list(session.scalars(select(Component).order_by(Component.name)))


def get_component(session: Session, name: str) -> Component:
    """The component called ``name``; NotFound naming it otherwise."""
    component = session.scalar(select(Component).where(Component.name == name))
    if component is None:
        raise NotFound(f"unknown component {name!r}")
    return component
