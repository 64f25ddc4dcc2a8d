"""Components: the things whose revisions are measured, and their settings."""

from __future__ import annotations

import difflib
from pathlib import Path

from redline.agent.checkout import refused_repo, without_credentials
from redline.recording.format import COMMIT_HASH
from redline.server.models import HELD, Component, Job, JobState, Revision
from redline.server.schemas.components import ComponentCreate, ComponentOut, ComponentSettings
from redline.server.services.errors import BadRequest, Conflict, NotFound, Unprocessable
from redline.server.services.repos import repo_key
from sqlalchemy import Select, and_, func, literal, or_, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session


def component_out(component: Component) -> ComponentOut:
    """The component as the API shows it: its webhook secret only as whether there is one."""
    return ComponentOut(
        name=component.name,
        repo=component.repo,
        branch=component.branch,
        suite=component.suite,
        executions=component.executions,
        host_labels=list(component.host_labels or []),
        description=component.description,
        has_webhook_secret=bool(component.webhook_secret),
        created=component.created,
    )


def check_repo(repo: str, allow_file: bool) -> None:
    """Unprocessable unless a performance host may fetch ``repo`` (empty: none set yet); a local
    one must be a folder here (local paths are for one machine, `redline up`'s: a trial's
    mistyped path was taken, and its first job failed inside a long git command line)."""
    reason = refused_repo(repo, allow_file) if repo else None
    scheme_less = repo[7:] if repo[:7].lower() == "file://" else repo
    local = scheme_less if scheme_less.startswith("/") else None
    if reason is None and local is not None and not Path(local).is_dir():
        reason = "no such folder on this machine (a local repository is read where it is)"
    if reason is not None:
        raise Unprocessable(f"repo {without_credentials(repo)[:200]!r}: {reason}")


def create_component(
    session: Session, data: ComponentCreate, allow_file: bool = False
) -> Component:
    check_repo(data.repo, allow_file)
    held = _named_alike(session, data.name)
    if held is not None and held != data.name:
        # 'hasher' and 'Hasher' were two components, and a report to one never reached the
        # other's pages (a trial)
        raise Conflict(
            f"component {held!r} already exists, and names that differ only in case would be "
            f"taken for each other: use {held!r}, or choose a name other than {data.name!r}"
        )
    component = Component(**data.model_dump())
    component.webhook_secret = data.webhook_secret or None
    component.repo_key = repo_key(data.repo)
    session.add(component)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        raise Conflict(f"component {data.name!r} already exists") from None
    return component


def update_component(
    session: Session, name: str, data: ComponentSettings, allow_file: bool = False
) -> Component:
    """Change the settings given (fields left out stay as they are)."""
    component = get_component(session, name)
    if data.repo is not None:
        check_repo(data.repo, allow_file)
    for field, value in data.model_dump(exclude_unset=True).items():
        if value is None and field != "webhook_secret":
            continue  # null means "unchanged" for every setting but the secret
        setattr(component, field, value)
    component.webhook_secret = component.webhook_secret or None
    component.repo_key = repo_key(component.repo)
    if data.host_labels is not None:
        # its jobs not yet run ask for the hosts it asks for now (a trial's job kept a label no
        # host had, and waited for ever); a host holding one keeps it until its lease ends
        session.execute(
            update(Job)
            .where(
                Job.revision_id.in_(
                    select(Revision.id).where(Revision.component_id == component.id)
                ),
                Job.state.in_((JobState.queued, *HELD)),
            )
            .values(labels=list(data.host_labels))
        )
    session.commit()
    return component


def list_components(session: Session) -> list[Component]:
    return list(session.scalars(select(Component).order_by(Component.name)))


def get_component(session: Session, name: str) -> Component:
    """The component called ``name``; NotFound naming it otherwise."""
    component = session.scalar(select(Component).where(Component.name == name))
    if component is None:
        held = _named_alike(session, name)
        hint = f" (names are case-sensitive: did you mean {held!r}?)" if held else ""
        if not held and (near := _spelt_alike(session, name)):
            hint = f" (did you mean {near!r}?)"  # a trial's 'planer' for 'planner' got no hint
        raise NotFound(f"unknown component {name!r}{hint}")
    return component


def _spelt_alike(session: Session, name: str) -> str | None:
    """The component name closest to ``name`` when one differs by a letter or two."""
    names = list(session.scalars(select(Component.name).order_by(Component.id).limit(10_000)))
    near = difflib.get_close_matches(name, names, n=1, cutoff=0.8)
    return near[0] if near else None


def _named_alike(session: Session, name: str) -> str | None:
    """The name of a component called ``name`` but for case, if there is one."""
    return session.scalar(
        select(Component.name).where(func.lower(Component.name) == name.lower()).limit(1)
    )


def get_revision(
    session: Session, component: Component, title: str, exact: bool = False
) -> Revision:
    """The component's revision titled ``title``, or else (unless ``exact``: what deletes or
    moves a revision names it by its title) of the commit whose hash it is, full or
    abbreviated (a trial's `ci wait --revision 2b2a811`, and with the full SHA, waited 2
    minutes for a revision titled by 12 digits, and gave up); NotFound naming both otherwise,
    BadRequest naming the revisions of several commits a too short hash starts."""
    revision = session.scalar(
        select(Revision).where(Revision.component_id == component.id, Revision.title == title)
    )
    if revision is not None:
        return revision
    if not exact and COMMIT_HASH.fullmatch(title):
        found = session.scalars(_of_commit(component, title).limit(AMBIGUOUS + 1)).all()
        if found and all(same_commit(found[0].commit, other.commit) for other in found):
            return found[0]  # one commit (reported under two titles before they were one)
        if found:
            named = ", ".join(repr(r.title) for r in found[:AMBIGUOUS])
            raise BadRequest(  # not "no revision": `ci wait` would wait for it to appear
                f"the hash {title!r} starts the commits of several of component "
                f"{component.name!r}'s revisions ({named}"
                f"{', ...' if len(found) > AMBIGUOUS else ''}): give more of it"
            )
    raise NotFound(f"component {component.name!r} has no revision {title!r}")


#: revisions named when an abbreviated hash is ambiguous
AMBIGUOUS = 3


def same_commit(first: str, second: str) -> bool:
    """Do two commit names name one commit: equal, or hashes of 7 hex digits or more one of
    which abbreviates the other (a 12-digit title's commit and the full SHA)."""
    if first == second:
        return True
    if not (COMMIT_HASH.fullmatch(first) and COMMIT_HASH.fullmatch(second)):
        return False
    first, second = first.lower(), second.lower()
    return first.startswith(second) or second.startswith(first)


def revision_of_commit(session: Session, component: Component, commit: str) -> Revision | None:
    """The component's first revision of ``commit`` (`same_commit`), whatever its title; None
    for a name that is not a hash (a branch, "main", names a commit that moves)."""
    if not COMMIT_HASH.fullmatch(commit):
        return None
    return session.scalars(_of_commit(component, commit).limit(1)).first()


def _of_commit(component: Component, commit: str) -> Select[Revision]:
    """The component's revisions of ``commit``, a hash (`same_commit`), first reported first."""
    stored, given = func.lower(Revision.commit), commit.lower()
    return (
        select(Revision)
        .where(
            Revision.component_id == component.id,
            or_(
                stored.startswith(given),
                and_(
                    Revision.commit.regexp_match(COMMIT_HASH.pattern),
                    literal(given).startswith(stored),
                ),
            ),
        )
        .order_by(Revision.id)
    )
