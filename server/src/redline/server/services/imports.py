"""Results that did not come from a Redline recording: LNT reports and generic JSON results.

An import is one execution of a revision (created if new, without queued jobs): its body is kept
in the storage folder as the "recording", its samples in Parquet beside it, and its summaries
and series are the same rows ingestion writes, so detection, the read API and the UI treat
imported history like measured history. Importing the same body again stores nothing new.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from redline.recording import SeriesKey, canonical_params
from redline.server.models import Execution, Host, Job, JobState, Revision, Summary
from redline.server.schemas_intake import ImportResult, ResultsImport
from redline.server.services.components import get_component
from redline.server.services.revisions import order_key
from redline.server.storage import samples_path
from redline.worker.ingest import _series_ids, _write_samples, summarize
from sqlalchemy import func, select
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


def _revision(session: Session, run: ImportedRun) -> Revision:
    component = get_component(session, run.component)
    revision = session.scalar(
        select(Revision).where(
            Revision.component_id == component.id, Revision.title == run.revision
        )
    )
    if revision is None:
        revision = Revision(
            component=component,
            title=run.revision,
            sort_key=run.sort_key,
            order_key=order_key(run.sort_key),
            commit=run.commit,
            repo=component.repo,
            branch=component.branch,
        )
        session.add(revision)
        session.flush()
    return revision


def _host(session: Session, name: str) -> Host | None:
    if not name:
        return None
    host = session.scalar(select(Host).where(Host.name == name))
    if host is None:
        host = Host(name=name, fingerprint={"imported": True}, labels=[])
        session.add(host)
    return host


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
        reason="imported",
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
    session: Session, storage_dir: Path, run: ImportedRun, body: bytes, suffix: str = ".json"
) -> ImportResult:
    """Store the run as one execution; a body imported before returns its execution."""
    sha256 = hashlib.sha256(body).hexdigest()
    known = session.scalar(select(Execution).where(Execution.sha256 == sha256))
    if known is not None:
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
    revision = _revision(session, run)
    job = _job(session, revision, _host(session, run.host))
    path = _keep(storage_dir, body, sha256, suffix)
    execution = Execution(
        job=job,
        revision_id=revision.id,
        recording_path=str(path),
        sha256=sha256,
        size=len(body),
        meta={"imported": suffix[1:]},
    )
    session.add(execution)
    session.flush()
    ids = _series_ids(session, revision.component_id, sorted(run.samples))
    summaries = {
        key: summarize(np.asarray(values, dtype=np.float64)) for key, values in run.samples.items()
    }
    session.add_all(
        Summary(execution_id=execution.id, series_id=ids[key], **stats)
        for key, stats in summaries.items()
        if stats is not None
    )  # None: no finite
    _write_samples(samples_path(path), ids, run.samples)
    session.commit()
    return ImportResult(
        component=run.component,
        revision=revision.title,
        revision_id=revision.id,
        execution_id=execution.id,
        series=sum(stats is not None for stats in summaries.values()),
        created=True,
    )
