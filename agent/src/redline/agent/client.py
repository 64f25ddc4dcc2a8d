"""The agent's side of the job protocol (docs/contracts-agent-server.md), over HTTP."""

from __future__ import annotations

import hashlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx

UPLOAD_CHUNK = 1 << 20


class LeaseLost(RuntimeError):
    """The server gave this job's lease to someone else."""


class UploadRejected(RuntimeError):
    """The server refused the recording (4xx): retrying the same file cannot help."""


class Refused(RuntimeError):
    """The server refused this agent's token for what it asked (401, 403): asking again, with
    the same token, cannot help."""


class ServerUnavailable(RuntimeError):
    """The server could not be reached or answered 5xx after every attempt: try again later."""


def _detail(answer: httpx.Response) -> str:
    """The server's reason (its JSON ``detail``), else the start of what answered (a proxy's
    page)."""
    try:
        detail = answer.json().get("detail")
    except (ValueError, AttributeError):  # not JSON, or not an object
        detail = None
    return str(detail) if detail else f"{answer.status_code} {answer.text[:300]}"


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(UPLOAD_CHUNK), b""):
            digest.update(block)
    return digest.hexdigest()


def _chunks(path: Path) -> Iterator[bytes]:
    with open(path, "rb") as stream:
        yield from iter(lambda: stream.read(UPLOAD_CHUNK), b"")


class ServerClient:
    def __init__(self, server: str, token: str, host: str, *, timeout: float = 30.0) -> None:
        self.host = host
        self._http = httpx.Client(
            base_url=server.rstrip("/"),
            timeout=timeout,
            headers={"Authorization": f"Bearer {token}"},
        )

    def close(self) -> None:
        self._http.close()

    def register(self, fingerprint: dict[str, Any], labels: list[str]) -> int:
        answer = self._http.post(
            "/api/v1/agent/register",
            json={
                "name": self.host,
                "fingerprint": fingerprint,
                "labels": labels,
            },
        )
        if answer.status_code in (401, 403):  # a token revoked, or not this host's or labels'
            raise Refused(f"the server refused to register {self.host!r}: {_detail(answer)}")
        answer.raise_for_status()
        return int(answer.json()["host_id"])

    def lease(self, wait: int = 0) -> dict[str, Any] | None:
        """The next job, or None; with ``wait`` the server holds the call up to that long."""
        answer = self._http.post(
            "/api/v1/agent/lease",
            json={"host": self.host},
            params={"wait": wait} if wait else None,
            timeout=(self._http.timeout.read or 0) + wait if wait else httpx.USE_CLIENT_DEFAULT,
        )
        if answer.status_code == 204:
            return None
        answer.raise_for_status()
        job = dict(answer.json())
        # the id names the job's folders (`job-{id}`), which are emptied: a number, or nothing
        # is run (a review: a server, or a man in the middle of plain http, could have sent
        # "x/../..")
        if type(job.get("id")) is not int:
            raise ValueError(f"the server leased a job whose id is no number: {job.get('id')!r}")
        return job

    def heartbeat(self, job_id: int) -> None:
        answer = self._http.post(f"/api/v1/jobs/{job_id}/heartbeat", json={"host": self.host})
        if answer.status_code == 409:
            raise LeaseLost(f"job {job_id}: {answer.text}")
        answer.raise_for_status()

    def fail(self, job_id: int, reason: str, of_commit: bool = False) -> None:
        """Fail the job this host holds (``of_commit``: for a fault of the commit itself, which
        every execution of it meets); a 409 (no longer ours) is ignored."""
        body = {"host": self.host, "reason": reason[-4000:], "of_commit": of_commit}
        self._http.post(f"/api/v1/jobs/{job_id}/fail", json=body)

    def release(self, job_id: int) -> None:
        """Give the job back to the queue without counting an attempt."""
        answer = self._http.post(f"/api/v1/jobs/{job_id}/release", json={"host": self.host})
        if answer.status_code != 409:  # 409: no longer ours, nothing to give back
            answer.raise_for_status()

    def upload(
        self, job_id: int, recording: Path, *, attempts: int = 5, backoff: float = 1.0
    ) -> int:
        """Stream the recording; retried with exponential backoff on network errors and 5xx.

        The server keys uploads by sha256, so a retry after a lost answer never doubles a result.
        Raises UploadRejected on a 4xx, ServerUnavailable when every attempt failed.
        """
        digest = sha256_of(recording)
        headers = {
            "X-Redline-Sha256": digest,
            "X-Redline-Host": self.host,
            "Content-Type": "application/octet-stream",
            "Content-Length": str(recording.stat().st_size),
        }
        problem = ""
        for attempt in range(1, attempts + 1):
            if attempt > 1:
                time.sleep(backoff * 2 ** (attempt - 2))
            try:
                answer = self._http.put(
                    f"/api/v1/jobs/{job_id}/recording", content=_chunks(recording), headers=headers
                )
            except httpx.TransportError as exc:
                problem = f"{type(exc).__name__}: {exc}"
                continue
            if answer.status_code >= 500:
                problem = f"{answer.status_code}: {answer.text[:500]}"
                continue
            if answer.status_code >= 400:
                raise UploadRejected(
                    f"upload of {recording.name} refused ({answer.status_code}): {answer.text}"
                )
            return int(answer.json()["execution_id"])
        raise ServerUnavailable(
            f"upload of {recording.name} for job {job_id} failed {attempts} times; last: {problem}"
        )
