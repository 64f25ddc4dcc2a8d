"""Deleting a component (admin): its whole history — revisions, jobs, executions, summaries,
verdicts, regressions and their triage, the alerts about it, its models, subscriptions and
settings — in one transaction, then its files (recordings, sample tables, model files).

Two new users registered a component by mistake and could not remove it (405): it stayed on the
home page and in every filter. Nothing else is touched: another component's rows, the hosts, the
tokens (but for its name among the components a token is bound to: `_unbind`). A component whose
jobs a host holds, whose results wait to be ingested, or whose model training or re-analysis is
under way, is refused (409): deleting under them would fail them halfway (and leave a model file no
row names).

A revision is deleted alone only when nothing was measured of it (`delete_revision`): a commit
reported by mistake, say, whose checkout failed, stayed "failed" on the home page for good (a
new-user trial). A revision with results is part of the history later revisions were judged
against; it stays.
"""

from __future__ import annotations

import logging
from pathlib import Path

from redline.server.db import lock_component
from redline.server.models import (
    Alert,
    AlertedChange,
    ApiToken,
    Component,
    Detection,
    DetectionConfigRow,
    Execution,
    FigureCache,
    Job,
    JobState,
    Reanalysis,
    Regression,
    ResourceModelRow,
    Revision,
    Series,
    Summary,
)
from redline.server.services.components import get_component, get_revision
from redline.server.services.errors import Conflict
from redline.server.services.revision_reports import reports_take_turns
from redline.server.storage import samples_path
from sqlalchemy import ColumnElement, delete, func, or_, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)

#: a job in these states is in a host's hands or on its way to the worker
IN_FLIGHT = (JobState.leased, JobState.running, JobState.uploaded)
#: a model's training or a re-analysis in these states writes rows and files of the component
WORKING = ("queued", "running")


def delete_component(session: Session, name: str) -> dict[str, int]:
    """Delete the component called ``name`` and everything of it; how many revisions,
    executions, regressions and files went. NotFound for an unknown name; Conflict while one of
    its jobs is in flight (`IN_FLIGHT`), its model is trained or its history re-analysed
    (`WORKING`), or when a worker stored a row of it meanwhile."""
    component = get_component(session, name)
    session.refresh(component, with_for_update=True)  # a report of it waits for this
    revisions = select(Revision.id).where(Revision.component_id == component.id)
    series = select(Series.id).where(Series.component_id == component.id)
    jobs = session.execute(  # locked: a host cannot lease one of them meanwhile
        select(Job.state)
        .where(or_(Job.revision_id.in_(revisions), Job.confirms_revision_id.in_(revisions)))
        .with_for_update()
    ).scalars()
    busy = sum(state in IN_FLIGHT for state in jobs)
    working = [
        what
        for what, model in (("a model's training", ResourceModelRow), ("a re-analysis", Reanalysis))
        if _count(session, model, model.component_id == component.id, model.state.in_(WORKING))
    ]
    if busy or working:
        held = [f"{busy} job(s) held by a host or waiting to be ingested"] if busy else []
        raise Conflict(
            f"component {name!r} has {' and '.join(held + working)} under way: let them "
            "finish (or cancel its revisions' jobs), then delete it"
        )
    files = _files(session, component.id)
    counts = {
        "revisions": session.scalar(select(func.count()).select_from(revisions.subquery())) or 0,
        "executions": _count(session, Execution, Execution.revision_id.in_(revisions)),
        "regressions": _count(session, Regression, Regression.component_id == component.id),
    }
    ours = or_(AlertedChange.series_id.in_(series), AlertedChange.revision_id.in_(revisions))
    statements = (
        delete(AlertedChange).where(ours),
        delete(Alert).where(  # a subscription to every component alerted about this one
            or_(
                Alert.revision_id.in_(revisions),
                Alert.regression_id.in_(
                    select(Regression.id).where(Regression.component_id == component.id)
                ),
            )
        ),
        delete(Summary).where(Summary.series_id.in_(series)),
        delete(Detection).where(
            or_(Detection.revision_id.in_(revisions), Detection.series_id.in_(series))
        ),
        delete(Regression).where(Regression.component_id == component.id),
        delete(Execution).where(Execution.revision_id.in_(revisions)),
        delete(Job).where(
            or_(Job.revision_id.in_(revisions), Job.confirms_revision_id.in_(revisions))
        ),
        delete(Revision).where(Revision.component_id == component.id),
        delete(Series).where(Series.component_id == component.id),
        delete(DetectionConfigRow).where(DetectionConfigRow.component_id == component.id),
        delete(FigureCache).where(FigureCache.component_id == component.id),
        delete(Reanalysis).where(Reanalysis.component_id == component.id),
        delete(Component).where(Component.id == component.id),  # its models, alarms and
        # subscriptions (with their deliveries) go with it (ON DELETE CASCADE)
    )
    try:
        for statement in statements:
            session.execute(statement)
        counts["tokens_revoked"] = _unbind(session, name)
        session.commit()
    except IntegrityError:  # a worker stored a row of it meanwhile (a verdict, a fresh run)
        session.rollback()
        raise Conflict(f"component {name!r} changed while it was deleted: try again") from None
    counts["files"] = _remove(session, files)
    log.info("component %s deleted: %s", name, counts)
    return counts


def _unbind(session: Session, name: str) -> int:
    """Take the deleted component's name out of the tokens bound to it, so that none acts on a
    component made later under that name; a token bound to it alone is revoked, since bound
    to none it would act on every component (a reviewer's find). How many were revoked."""
    revoked = 0
    for token in session.scalars(select(ApiToken).where(~ApiToken.revoked)):
        if name in (token.components or []):
            token.components = [other for other in token.components if other != name]
            if not token.components:
                token.revoked, revoked = True, revoked + 1
    return revoked


def delete_revision(session: Session, name: str, title: str) -> dict[str, int | str]:
    """Delete a revision of the component called ``name`` of which nothing was measured, with
    its jobs: what went. NotFound for an unknown one; Conflict when it has results (they are
    part of the history later revisions were judged against), or while a host holds one of
    its jobs (cancel it first)."""
    revision = get_revision(session, get_component(session, name), title, exact=True)
    reports_take_turns(session, revision.component_id)  # a report of its commit waits
    lock_component(session, revision.component_id)  # so does a verdict of it
    mine = or_(Job.revision_id == revision.id, Job.confirms_revision_id == revision.id)
    states = list(session.scalars(select(Job.state).where(mine).with_for_update()))
    measured = _count(session, Execution, Execution.revision_id == revision.id)
    if measured:
        raise Conflict(
            f"revision {title!r} of {name!r} has {measured} execution(s) stored: its results "
            "are part of the history later revisions are judged against, and it stays (a wrong "
            'sort key is corrected by PATCH with {"sort_key": ...}; delete the component to '
            "remove its whole history)"
        )
    held = sum(state in IN_FLIGHT for state in states)
    if held:
        raise Conflict(
            f"revision {title!r} of {name!r} has {held} job(s) a host holds: cancel it "
            f"(POST .../revisions/{title}/cancel), then delete it"
        )
    try:
        session.execute(delete(AlertedChange).where(AlertedChange.revision_id == revision.id))
        session.execute(delete(Job).where(mine))
        # alerts about it: SET NULL; its cached charts: their data version names its revisions
        session.execute(delete(Revision).where(Revision.id == revision.id))
        session.commit()
    except IntegrityError:  # a worker stored a row of it meanwhile
        session.rollback()
        raise Conflict(f"revision {title!r} changed while it was deleted: try again") from None
    log.info("revision %s of %s deleted (%d jobs)", title, name, len(states))
    return {"deleted": title, "component": name, "jobs": len(states)}


def _count(session: Session, model: type, *where: ColumnElement[bool]) -> int:
    found: int | None = session.scalar(select(func.count()).select_from(model).where(*where))
    return found or 0


def _files(session: Session, component_id: int) -> tuple[list[str], list[str]]:
    """The recordings of the component's executions, and its models' files."""
    recordings = session.scalars(
        select(Execution.recording_path)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(Revision.component_id == component_id)
    ).all()
    models = session.scalars(
        select(ResourceModelRow.path).where(
            ResourceModelRow.component_id == component_id, ResourceModelRow.path != ""
        )
    ).all()
    return list(recordings), list(models)


def _remove(session: Session, files: tuple[list[str], list[str]]) -> int:
    """Remove the recordings (each with its sample table) that no remaining execution names (an
    upload is stored by its sha256: the same bytes for two components would be one file), and
    the model files; how many files were there."""
    recordings, models = files
    kept = set(
        session.scalars(
            select(Execution.recording_path).where(Execution.recording_path.in_(recordings))
        )
    )
    paths = [Path(path) for path in models]
    for recording in set(recordings) - kept:
        paths += [Path(recording), samples_path(recording)]
    removed = 0
    for path in paths:
        try:
            path.unlink()
            removed += 1
        except FileNotFoundError:
            pass  # pruned by retention before
        except OSError as exc:  # the rows are gone: a file left behind is logged, not fatal
            log.warning("component deletion: %s not removed: %s", path, exc)
    return removed
