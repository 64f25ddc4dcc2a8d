"""An admin's correction of a revision's sort key.

A CI system's sort key orders a component's revisions, and a ``ci`` token may give any: a trial
reported one with the time 4102444800 (the year 2100) and it sorted above every revision
reported after it, for good (a revision with results cannot be deleted). An admin gives it
the right key; the regressions that begin or end at it take the new order, and the history is
judged again in it (`detection_config.request_reanalysis`; the caller sends the task).
"""

from __future__ import annotations

from redline.server.db import lock_component
from redline.server.models import Component, Regression
from redline.server.services.components import get_component, get_revision
from redline.server.services.detection_config import request_reanalysis
from redline.server.services.revisions import order_key
from sqlalchemy import update
from sqlalchemy.orm import Session


def set_sort_key(session: Session, component_name: str, title: str, sort_key: str) -> Component:
    """Give the revision titled ``title`` the sort key ``sort_key`` and queue a re-analysis;
    returns its component. NotFound for an unknown component or revision."""
    component = get_component(session, component_name)
    lock_component(session, component.id)  # as the worker storing verdicts takes it
    revision = get_revision(session, component, title)
    revision.sort_key, revision.order_key = sort_key, order_key(sort_key)
    for kept, column in (
        (Regression.good_revision_id, "good_key"),
        (Regression.bad_revision_id, "bad_key"),
    ):
        session.execute(
            update(Regression).where(kept == revision.id).values({column: revision.order_key})
        )
    session.commit()
    request_reanalysis(session, component)
    return component
