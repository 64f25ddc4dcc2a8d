"""Revision histories stored as uploads would store them, on a test's database."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from redline.server.models import (
    DetectionConfigRow,
    Execution,
    Job,
    JobState,
    Regression,
    Revision,
)
from redline.server.schemas.components import ComponentCreate
from redline.server.schemas.revisions import RevisionCreate
from redline.server.services.components import create_component
from redline.server.services.revisions import create_revision
from redline.worker.detection import detect_revision
from redline.worker.ingest import ingest_execution

from tests.support.recordings import run_metadata, write_recording

#: every table a test empties before it starts (detections and regressions go with CASCADE)
TABLES = (
    "summary, series, execution, job, revision, component, host, api_token, web_user, web_session"
)
COMPONENT = "builder"


def add_execution(
    session,
    tmp_path: Path,
    component: str,
    title: str,
    sort_key: str,
    counters: dict[str, np.ndarray],
    **extra,
) -> Execution:
    """Report a revision and store a recording for its job, as an upload would."""
    return add_executions(session, tmp_path, component, title, sort_key, [counters], **extra)[0]


def add_executions(
    session,
    tmp_path: Path,
    component: str,
    title: str,
    sort_key: str,
    runs: list[Any],
    record: Callable[..., Path] = write_recording,
    **extra,
) -> list[Execution]:
    """Report a revision and store one recording per job (the component's ``executions``):
    ``record(path, run_metadata, run, **extra)`` writes each, by default `write_recording`
    with ``run`` the counters' samples."""
    revision = create_revision(
        session, RevisionCreate(component=component, title=title, sort_key=sort_key, commit="main")
    )
    assert len(revision.jobs) == len(runs), "the component's executions per revision"
    executions = []
    for job, counters in zip(
        sorted(revision.jobs, key=lambda j: j.execution_index), runs, strict=True
    ):
        name = f"{component}-{title}-{job.execution_index}"
        path = record(
            tmp_path / f"{name}.mcap",
            run_metadata(job, component, title, sort_key),
            counters,
            **extra,
        )
        executions.append(uploaded(session, job, path, name))
    session.commit()
    return executions


def uploaded(session, job: Job, path: Path, name: str) -> Execution:
    """Store the recording at ``path`` as ``job``'s execution, as an upload would (not yet
    committed); ``name`` makes its checksum unique."""
    execution = Execution(
        job_id=job.id,
        revision_id=job.revision_id,
        recording_path=str(path),
        sha256=name.ljust(64, "0"),
        size=path.stat().st_size,
    )
    job.state = JobState.uploaded
    job.attempts = max(job.attempts or 0, 1)  # leased once, as an agent that uploads has
    session.add(execution)
    return execution


def cpu_history(
    session,
    tmp_path: Path,
    cpus: list[np.ndarray | float],
    seed: int = 7,
    config: dict | None = None,
) -> list[Execution]:
    """Revisions r1.. of one component with a 'cpu' series; floats are means of 60 samples."""
    component = create_component(  # one a host could run: CI may report its revisions
        session,
        ComponentCreate(
            name=COMPONENT, repo=f"https://git.example/{COMPONENT}.git", suite="perf/redline.toml"
        ),
    )
    if config is not None:
        session.add(DetectionConfigRow(component_id=component.id, config=config))
        session.commit()
    rng = np.random.default_rng(seed)
    executions = []
    for number, cpu in enumerate(cpus, start=1):
        values = rng.normal(cpu, cpu / 20, 60) if isinstance(cpu, float) else cpu
        executions.append(
            add_execution(session, tmp_path, COMPONENT, f"r{number}", str(number), {"cpu": values})
        )
    return executions


def ingest_and_detect(database_url: str, executions: list[Execution]) -> None:
    """Ingest every execution, then detect each of their revisions once, in order."""
    for execution in executions:
        ingest_execution(database_url, execution.id)
    for revision_id in dict.fromkeys(execution.revision_id for execution in executions):
        detect_revision(database_url, revision_id)


def regression_between(session, good: Revision, bad: Revision, **fields: Any) -> Regression:
    """A regression of ``bad``'s component from ``good`` to ``bad``, stored (not committed), as
    grouping would make one; ``fields`` set more of it."""
    regression = Regression(
        component_id=bad.component_id,
        good_revision_id=good.id,
        bad_revision_id=bad.id,
        good_key=good.order_key,
        bad_key=bad.order_key,
        **fields,
    )
    session.add(regression)
    session.flush()
    return regression
