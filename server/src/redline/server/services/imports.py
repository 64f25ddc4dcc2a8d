"""Results that did not come from a Redline recording: LNT reports and generic JSON results.

An import is one execution of a revision (created if new, without queued jobs): its body is kept
in the storage folder as the "recording", its samples in Parquet beside it, and its summaries
and series are the same rows ingestion writes, so detection, the read API and the UI treat
imported history like measured history. Importing the same run again (`content_key`) stores
nothing new.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from redline.recording import SeriesKey, canonical_params
from redline.server.db import share_component
from redline.server.models import Component, Execution, Host, Job, JobState, Revision, Summary
from redline.server.schemas.imports import ImportResult, ResultsImport
from redline.server.services.analysed import unanalysed
from redline.server.services.components import get_component, revision_of_commit, same_commit
from redline.server.services.errors import Conflict, Forbidden
from redline.server.services.home import IMPORTED
from redline.server.services.ingestion import store_samples
from redline.server.services.reach import in_reach
from redline.server.services.revision_reports import cannot_run, reports_take_turns
from redline.server.services.revisions import order_key
from sqlalchemy import func, select
from sqlalchemy.dialects.postgresql import insert
from sqlalchemy.orm import Session

IMPORT_PROCESS = "benchmark"


@dataclass
class ImportedRun:
    """What an import brings, whatever its format."""

    component: str
    revision: str
    sort_key: str
    commit: str
    host: str
    samples: dict[SeriesKey, list[float]]
    #: the execution's metadata: the format imported, and what else the report says of the run
    meta: dict[str, str] = field(default_factory=lambda: {"imported": "json"})


def content_key(run: ImportedRun) -> str:
    """The sha256 of what an import says, not of how its body spells it: a trial's same
    samples, their series in another order (or its commit in capitals, its sort key written
    "1.0") were a new execution each time, counted again in every verdict. The sort key is left
    out: a revision's first one stands."""
    said = {
        "component": run.component,
        "revision": run.revision,
        "commit": run.commit.lower(),
        "host": run.host,
        "meta": run.meta,
        "samples": sorted(
            [key.case, key.phase, key.params, key.process, key.counter, values]
            for key, values in run.samples.items()
        ),
    }
    return hashlib.sha256(json.dumps(said, sort_keys=True).encode()).hexdigest()


def from_results(data: ResultsImport) -> ImportedRun:
    samples: dict[SeriesKey, list[float]] = {}
    for item in data.results:
        key = SeriesKey(
            item.case, item.phase, canonical_params(item.params), item.process, item.counter
        )
        samples.setdefault(key, []).extend(item.values)
    return ImportedRun(
        data.component, data.revision, data.sort_key, data.commit, data.host, samples
    )


#: the reason of an imported execution's job (an agent's job has none, or why it failed)
IMPORTED_JOB = "imported"


def _refuse_another_revisions_commit(
    session: Session, component: Component, run: ImportedRun
) -> None:
    """A Conflict when the import would make a new revision of a commit (a hash) that is another
    revision already: one commit, one revision, as CI's reports have it. A trial's i12b with
    i11's commit was a second revision of it. An import into a revision that exists is left to
    the checks after this (and one sent again to it is the import stored before)."""
    if not run.commit or session.scalar(
        select(Revision.id).where(
            Revision.component_id == component.id, Revision.title == run.revision
        )
    ):
        return
    reports_take_turns(session, component.id)  # a report of this commit meanwhile waits
    known = revision_of_commit(session, component, run.commit)
    if known is not None:
        raise Conflict(
            f"commit {run.commit!r} is revision {known.title!r} of {run.component!r} already: "
            "one commit is one revision (import under its title, where it is not measured by "
            "performance hosts)"
        )


def _revision(session: Session, run: ImportedRun, admin: bool) -> Revision:
    """The run's revision, created if new, locked: imports into one revision take turns, so
    each gets its own execution index (INSERT ... ON CONFLICT: concurrent imports never race).

    A component its performance hosts measure takes imports from an admin only: a ``ci``
    token's import stands for measurements no host made. A trial imported made-up results for
    a commit before CI reported it: the report then queued nothing, the gate passed a 4x CPU
    rise with a green commit status, and the made-up level hid the next commit's real
    regression from its confirmation pairs."""
    component = get_component(session, run.component)
    if not admin and cannot_run(component) is None:
        raise Forbidden(
            f"component {run.component!r} is measured by its performance hosts: results are "
            "imported into it with an admin token only (a ci token reports its commits, "
            "which the hosts then measure); import into a component without a repository or "
            "suite"
        )
    _refuse_another_revisions_commit(session, component, run)  # reports take turns first
    share_component(session, component.id)  # before the revision's row, as everyone does
    session.execute(
        insert(Revision)
        .values(
            component_id=component.id,
            title=run.revision,
            sort_key=run.sort_key,
            order_key=order_key(run.sort_key),
            commit=run.commit,
            repo=component.repo,
            branch=component.branch,
        )
        .on_conflict_do_nothing(index_elements=["component_id", "title"])
    )
    revision = session.scalars(
        select(Revision)
        .where(Revision.component_id == component.id, Revision.title == run.revision)
        .with_for_update()
    ).one()
    if run.commit and revision.commit and not same_commit(revision.commit, run.commit):
        raise Conflict(
            f"component {run.component!r} already has a revision {run.revision!r}, of commit "
            f"{revision.commit!r}; this import says {run.commit!r}"
        )
    measured = session.scalar(
        select(Job.id).where(Job.revision_id == revision.id, Job.reason != IMPORTED_JOB).limit(1)
    )
    if measured is not None:  # a ci token's import turned a confirmed regression green
        raise Conflict(
            f"revision {run.revision!r} of {run.component!r} is measured by performance hosts "
            f"(job {measured}): results are imported into revisions of their own only"
        )
    return revision


def _host(session: Session, name: str) -> Host | None:
    if not name:
        return None
    session.execute(
        insert(Host)
        .values(name=name, fingerprint=IMPORTED, labels=[])
        .on_conflict_do_nothing(index_elements=["name"])
    )
    return session.scalars(select(Host).where(Host.name == name)).one()


def _job(session: Session, revision: Revision, host: Host | None) -> Job:
    index = session.scalar(
        select(func.coalesce(func.max(Job.execution_index) + 1, 0)).where(
            Job.revision_id == revision.id
        )
    )
    job = Job(
        revision=revision,
        execution_index=index or 0,
        state=JobState.done,
        reason=IMPORTED_JOB,
        host=host,
    )
    session.add(job)
    return job


def _keep(storage_dir: Path, body: bytes, sha256: str, suffix: str) -> Path:
    folder = storage_dir / "imports"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{sha256}{suffix}"
    partial = path.with_suffix(".part")
    partial.write_bytes(body)
    os.replace(partial, path)
    return path


def store_import(
    session: Session,
    storage_dir: Path,
    run: ImportedRun,
    body: bytes,
    suffix: str = ".json",
    admin: bool = False,
) -> ImportResult:
    """Store the run as one execution; a run imported before (the same samples of the same
    series, revision, commit, host and report details, however the body spelt them) returns
    its execution. ``admin``: the caller holds the admin scope (`_revision`)."""
    sha256 = content_key(run)
    revision = _revision(session, run, admin)  # locked: the same body sent twice at once waits
    known = session.scalar(select(Execution).where(Execution.sha256 == sha256))
    if known is not None:
        session.rollback()  # nothing new; an emptied revision made just now is not kept
        revision = session.get_one(Revision, known.revision_id)
        count = session.scalar(
            select(func.count()).select_from(Summary).where(Summary.execution_id == known.id)
        )
        return ImportResult(
            component=run.component,
            revision=revision.title,
            revision_id=revision.id,
            execution_id=known.id,
            series=count or 0,
            created=False,
        )
    job = _job(session, revision, _host(session, run.host))
    path = _keep(storage_dir, body, sha256, suffix)
    execution = Execution(
        job=job,
        revision_id=revision.id,
        recording_path=str(path),
        sha256=sha256,
        size=len(body),
        meta=run.meta,
    )
    session.add(execution)
    session.flush()
    series = store_samples(session, execution, revision.component_id, run.samples)
    unanalysed(session, [revision.id])  # judged again: the walk the route queues marks it
    session.commit()
    # and the later revisions that read it, as after an ingestion, in a transaction of their
    # own: this one holds the revision's row from its start, and waiting here for a later
    # revision an import into it held, while that import waited for a series this one made,
    # deadlocked (a CI run's concurrent imports, 503). A detection that judged them without
    # this run meanwhile is undone here, or finds their inputs moved and leaves them pending.
    unanalysed(session, in_reach(session, revision.id))
    session.commit()
    return ImportResult(
        component=run.component,
        revision=revision.title,
        revision_id=revision.id,
        execution_id=execution.id,
        series=series,
        created=True,
    )
