"""An admin's correction of a revision's sort key.

A CI system's sort key orders a component's revisions, and a ``ci`` token may give any: a trial
reported one with the time 4102444800 (the year 2100) and it sorted above every revision
reported after it, for good (a revision with results cannot be deleted). An admin gives it
the right key, and the history is judged again in the new order
(`detection_config.request_reanalysis`, in the same transaction; the caller sends the task).

Refused (409, saying why) while what the order decided is still in use: a regression that
begins or ends at the revision (moved, its range could end before it begins, and judging again
would withdraw it and open a new one without its triage), and
confirmation runs of it or against it not yet ended (their pairs were chosen by the old order).
"""

from __future__ import annotations

from redline.server.db import lock_component
from redline.server.models import UNENDED, WITHDRAWN, Component, Job, Regression
from redline.server.services.components import get_component, get_revision
from redline.server.services.detection_config import request_reanalysis
from redline.server.services.errors import Conflict
from redline.server.services.revisions import order_key
from sqlalchemy import func, or_, select
from sqlalchemy.orm import Session


def set_sort_key(session: Session, component_name: str, title: str, sort_key: str) -> Component:
    """Give the revision titled ``title`` the sort key ``sort_key`` and queue a re-analysis;
    returns its component. NotFound for an unknown component or revision, Conflict (nothing
    changed) while a regression or unfinished confirmation runs depend on its place."""
    component = get_component(session, component_name)
    lock_component(session, component.id)  # as the worker storing verdicts takes it
    revision = get_revision(session, component, title, exact=True)
    bounding = session.scalars(
        select(Regression.id).where(
            Regression.confirmation != WITHDRAWN,
            or_(
                Regression.good_revision_id == revision.id,
                Regression.bad_revision_id == revision.id,
            ),
        )
    ).all()
    if bounding:
        named = ", ".join(f"#{ident}" for ident in sorted(bounding))
        raise Conflict(
            f"revision {title!r} begins or ends regression(s) {named}: moved, their ranges would "
            "no longer hold, and judging again would withdraw them and open new ones without "
            "their triage; a key is corrected while no regression begins or ends at it"
        )
    pairs = session.scalar(
        select(func.count())
        .select_from(Job)
        .where(
            Job.state.in_(UNENDED),
            Job.pair > 0,
            or_(Job.confirms_revision_id == revision.id, Job.revision_id == revision.id),
        )
    )
    if pairs:
        raise Conflict(
            f"revision {title!r} has {pairs} confirmation run(s) not yet ended, chosen by its "
            "place in the old order: wait for them or cancel them "
            f"(POST .../revisions/{title}/cancel), then correct its key"
        )
    revision.sort_key, revision.order_key = sort_key, order_key(sort_key)
    request_reanalysis(session, component)  # commits the new key with it
    return component
