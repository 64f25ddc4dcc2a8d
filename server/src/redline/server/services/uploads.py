"""Recordings uploaded by agents: streamed to storage, checked, and stored only when valid.

A file is staged under ``incoming/`` while it arrives; only a finished Redline recording whose
``redline.run`` metadata matches its job is moved to ``recordings/<sha256>.mcap`` and becomes an
execution, so a bad upload leaves nothing half-stored.
"""

from __future__ import annotations

import hashlib
import os
import re
import uuid
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

from redline.recording import Recording, RecordingError, read_recording
from redline.recording.mcap_bytes import MAX_UNPACKED_BYTES
from redline.server.models import Execution, Job, JobState
from redline.server.services.errors import (
    BadRequest,
    Conflict,
    NotFound,
    TooLarge,
    Unprocessable,
)
from redline.server.services.fresh_runs import mark_waiting
from redline.server.services.jobs import ensure_held, holder
from redline.server.services.measured_commit import commit_mismatch, pin_measured
from sqlalchemy import select
from sqlalchemy.orm import Session


@dataclass(frozen=True)
class Staged:
    path: Path
    sha256: str
    size: int


@dataclass(frozen=True)
class Accepted:
    execution_id: int
    created: bool
    needs_ingest: bool


async def stage_upload(chunks: AsyncIterator[bytes], storage_dir: Path, limit: int) -> Staged:
    """Write the request body to ``incoming/``, hashing as it goes; TooLarge past ``limit``."""
    incoming = storage_dir / "incoming"
    incoming.mkdir(parents=True, exist_ok=True)
    path = incoming / f"{uuid.uuid4().hex}.part"
    digest = hashlib.sha256()
    size = 0
    try:
        with open(path, "wb") as out:
            async for chunk in chunks:
                size += len(chunk)
                if size > limit:
                    raise TooLarge(f"recording is larger than the limit of {limit} bytes")
                digest.update(chunk)
                out.write(chunk)
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    return Staged(path, digest.hexdigest(), size)


def _mismatch(recording: Recording, job: Job) -> str:
    """What in the recording's ``redline.run`` metadata contradicts the job, or ''."""
    revision = job.revision
    expected = {
        "job_id": str(job.id),
        "component": revision.component.name,
        "revision_title": revision.title,
        "revision_sort_key": revision.sort_key,
        "execution_index": str(job.execution_index),
    }
    run = recording.run
    for key, value in expected.items():
        if key not in run:
            return f"{recording.path.name}: redline.run metadata has no {key!r}"
        if run[key] != value:
            return (
                f"{recording.path.name}: redline.run {key} is {run[key]!r} "
                f"but job {job.id} expects {value!r}"
            )
    problem = commit_mismatch(run, revision, job.id)
    if problem:
        return f"{recording.path.name}: {problem}"
    return ""


def _check(staged: Staged, job: Job, unpacked: int) -> tuple[Recording | None, str]:
    try:
        recording = read_recording(staged.path, strict=True, max_unpacked=unpacked)
    except RecordingError as exc:
        return None, f"recording for job {job.id}: {exc}".replace(staged.path.name, "upload")
    return recording, _mismatch(recording, job).replace(staged.path.name, "upload")


def _existing(session: Session, job: Job, sha256: str, host_name: str) -> Accepted | None:
    """The outcome of a repeated upload, or None when this is the job's first recording.

    Only the host holding the job may upload; only the host that uploaded it may resend.
    """
    same = session.scalar(select(Execution).where(Execution.sha256 == sha256))
    if same is not None and same.job_id != job.id:
        raise Conflict(f"this recording is already stored for job {same.job_id}")
    if same is not None:
        if holder(job) != host_name:
            raise Conflict(
                f"job {job.id}'s recording was uploaded by host {holder(job)!r}, not {host_name!r}"
            )
        return Accepted(same.id, created=False, needs_ingest=job.state == JobState.uploaded)
    if job.execution is not None:
        raise Conflict(
            f"job {job.id} already has a different recording (sha256 {job.execution.sha256})"
        )
    ensure_held(job, host_name)
    return None


_SHA256 = re.compile(r"[0-9a-f]{64}")


def check_before_reading(session: Session, job_id: int, claimed_sha256: str, host: str) -> None:
    """Refuse at once, before a byte of the body is read, an upload that could not be stored:
    a hash header that is no sha256 (422), an unknown job (404), one ``host`` never held (409,
    naming no other host), one that takes no recording any more (409: it failed or was
    cancelled, or it has another one; only a resend of the recording it has is read). A
    trial's 200 MB were read for a job that did not exist; a failed job's upload was read,
    then refused for its hash."""
    claimed = claimed_sha256.strip().lower()
    if not _SHA256.fullmatch(claimed):
        raise Unprocessable(
            f"X-Redline-Sha256 {claimed_sha256[:80]!r} is not a sha256 (64 hex digits)"
        )
    job = session.get(Job, job_id)
    if job is None:
        raise NotFound(f"unknown job {job_id}")
    if holder(job) != host:
        raise Conflict(f"job {job_id} is not held by host {host!r}")
    if job.execution is None:
        ensure_held(job, host)
    elif job.execution.sha256 != claimed:
        raise Conflict(
            f"job {job_id} already has a different recording (sha256 {job.execution.sha256})"
        )


def accept_recording(
    session: Session,
    storage_dir: Path,
    job_id: int,
    staged: Staged,
    claimed_sha256: str,
    host_name: str,
    max_unpacked: int = MAX_UNPACKED_BYTES,
) -> Accepted:
    """Store a staged upload from ``host_name`` as the job's execution, or refuse it naming
    the problem.

    Invalid recordings fail the job with the same reason they are refused with, among them
    one whose chunks unpack to more than ``max_unpacked`` bytes.
    """
    if claimed_sha256.strip().lower() != staged.sha256:
        raise BadRequest(
            f"X-Redline-Sha256 {claimed_sha256!r} does not match the "
            f"{staged.size} bytes received (sha256 {staged.sha256}); send it again"
        )
    job = session.scalar(select(Job).where(Job.id == job_id).with_for_update())
    if job is None:
        raise NotFound(f"unknown job {job_id}")
    repeated = _existing(session, job, staged.sha256, host_name)
    if repeated is not None:
        return repeated
    recording, problem = _check(staged, job, max_unpacked)
    if recording is not None and not problem:  # its revision's commit, pinned by the first
        problem = pin_measured(session, job.revision, recording.run)
    if problem or recording is None:
        job.state, job.reason, job.lease_expires_at = JobState.failed, problem, None
        if job.remeasures_job_id is not None:  # the sweep has those that waited judged
            mark_waiting(session, job.revision_id)
        session.commit()
        raise BadRequest(problem)
    final = storage_dir / "recordings" / f"{staged.sha256}.mcap"
    final.parent.mkdir(parents=True, exist_ok=True)
    os.replace(staged.path, final)
    try:
        execution = Execution(
            job=job,
            revision_id=job.revision_id,
            recording_path=str(final),
            sha256=staged.sha256,
            size=staged.size,
            meta=dict(recording.metadata),
        )
        session.add(execution)
        job.state, job.lease_expires_at, job.reason = JobState.uploaded, None, ""
        session.commit()
    except BaseException:
        final.unlink(missing_ok=True)
        raise
    return Accepted(execution.id, created=True, needs_ingest=True)
