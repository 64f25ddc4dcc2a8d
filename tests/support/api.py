"""A driver for the HTTP API through the real app, with settings of the test's choosing."""

from __future__ import annotations

import hashlib
import json
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np
import redis
from fastapi.testclient import TestClient
from redline.server.app import create_app
from redline.server.core.config import Settings
from redline.server.core.tasks import QUEUE_KINDS, queue_of
from redline.server.db import migrate, session_factory
from redline.server.models import Job, utcnow
from redline.server.services.tokens import issue_token
from sqlalchemy import text, update
from sqlalchemy.orm import Session

from tests.support.history import TABLES
from tests.support.recordings import write_recording
from tests.support.servers import Services


def commit_of(title: str) -> str:
    """A made-up commit hash for the revision ``title``, one per title: a report names its
    commit by its hash (`require_hash`), and one commit under two titles is one revision."""
    return hashlib.sha1(title.encode()).hexdigest()


SCOPES = ("admin", "ci", "triage", "agent", "read")
HOST = "perf1"  # the host the tests' ``agent`` token is bound to
LABELS = ("gpu", "quiet")  # the labels the tests' agent tokens may register their hosts with


@dataclass
class Api:
    client: TestClient
    settings: Settings
    tokens: dict[str, dict[str, str]]  # scope -> Authorization header ("agent": perf1's)

    def headers(self, scope: str, host: str = HOST) -> dict[str, str]:
        """The Authorization header of a token with ``scope``; with ``agent``, the token of
        ``host`` (an agent token is bound to one host), issued on first use."""
        if scope != "agent" or host == HOST:
            return self.tokens[scope]
        key = f"agent@{host}"
        if key not in self.tokens:
            with session_factory(self.settings.database_url)() as session:
                secret = issue_token(session, f"agent-{host}", "agent", host, LABELS)[1]
            self.tokens[key] = {"Authorization": f"Bearer {secret}"}
        return self.tokens[key]

    def post(self, path: str, scope: str, body: dict) -> object:
        """POST ``body``; with ``agent``, as the host the body names (its host, or the name it
        registers)."""
        host = body.get("host") or body.get("name") or HOST
        return self.client.post(path, json=body, headers=self.headers(scope, host))

    def component(
        self, name: str = "builder", executions: int = 1, host_labels: list[str] | None = None
    ) -> None:
        answer = self.post(
            "/api/v1/components",
            "admin",
            {
                "name": name,
                "repo": f"https://git.example/{name}.git",
                "suite": "perf/redline.toml",
                "executions": executions,
                "host_labels": host_labels or [],
            },
        )
        assert answer.status_code == 201, answer.text

    def revision(self, title: str, sort_key: str, component: str = "builder") -> dict:
        answer = self.post(
            "/api/v1/revisions",
            "ci",
            {
                "component": component,
                "title": title,
                "sort_key": sort_key,
                "commit": commit_of(title),
            },
        )
        assert answer.status_code == 201, answer.text
        return answer.json()

    def lease(self, host: str = "perf1") -> dict | None:
        answer = self.post("/api/v1/agent/lease", "agent", {"host": host})
        assert answer.status_code in (200, 204), answer.text
        return answer.json() if answer.status_code == 200 else None

    def upload(
        self,
        job_id: int,
        data: bytes,
        sha256: str | None = None,
        host: str = "perf1",
        scope: str = "agent",
    ) -> object:
        headers = {
            **self.headers(scope, host),
            "X-Redline-Host": host,
            "X-Redline-Sha256": sha256 or hashlib.sha256(data).hexdigest(),
        }
        return self.client.put(f"/api/v1/jobs/{job_id}/recording", content=data, headers=headers)

    def queued_tasks(self) -> list[tuple[str, str]]:
        """(task name, its arguments) of the messages the API sent, waiting in the real broker's
        queues (no worker runs in these tests)."""
        broker = redis.Redis.from_url(self.settings.redis_url)
        messages = [
            json.loads(raw)
            for kind in QUEUE_KINDS
            for raw in broker.lrange(queue_of(self.settings, kind), 0, -1)
        ]
        return [(m["headers"]["task"], m["headers"]["argsrepr"]) for m in messages]

    def job(self, job_id: int) -> dict:
        with session_factory(self.settings.database_url)() as session:
            title = session.get_one(Job, job_id).revision.title
        detail = self.client.get(f"/api/v1/components/builder/revisions/{title}").json()
        return next(job for job in detail["jobs"] if job["id"] == job_id)


_MIGRATED: set[str] = set()


def emptied_with_tokens(database_url: str) -> dict[str, dict[str, str]]:
    """Empty the (migrated) database and issue one token per scope, named after it (the
    agent's bound to ``HOST``)."""
    with session_factory(database_url)() as session:
        session.execute(text(f"TRUNCATE {TABLES} RESTART IDENTITY CASCADE"))
        session.commit()
        return {scope: {"Authorization": f"Bearer {_issue(session, scope)}"} for scope in SCOPES}


def _issue(session: Session, scope: str) -> str:
    """The secret of a new token named after ``scope`` (the agent's bound to ``HOST``)."""
    if scope == "agent":
        return issue_token(session, scope, scope, HOST, LABELS)[1]
    return issue_token(session, scope, scope)[1]


@contextmanager
def api_with(services: Services, tmp_path: Path, **settings: Any) -> Iterator[Api]:
    """An app on an emptied, migrated database with one token per scope (named after it)."""
    if services.database_url not in _MIGRATED:
        migrate(services.database_url)
        _MIGRATED.add(services.database_url)
    defaults = {
        "redis_url": services.redis_url,
        "storage_dir": tmp_path / "storage",
        "queue": f"test-{uuid.uuid4().hex[:8]}",
    }
    config = Settings(database_url=services.database_url, **{**defaults, **settings})
    tokens = emptied_with_tokens(config.database_url)
    with TestClient(create_app(config)) as client:
        yield Api(client, config, tokens)


def recording_for(
    job: dict,
    path: Path,
    cpu: float = 20.0,
    seed: int = 0,
    extra: tuple[str, bytes] | None = None,
    **run: str,
) -> bytes:
    """A finished recording made for the leased ``job``; ``run`` overrides metadata fields;
    ``extra`` is one more message, as given (`write_recording`)."""
    rng = np.random.default_rng(seed)
    metadata = {
        "job_id": str(job["id"]),
        "component": job["component"],
        "revision_title": job["revision"]["title"],
        "revision_sort_key": job["revision"]["sort_key"],
        "commit": job["commit"],
        "execution_index": str(job["execution_index"]),
        **run,
    }
    counters = {"cpu": rng.normal(cpu, cpu / 10, 150), "rss": rng.normal(5e7, 1e5, 150)}
    return write_recording(path, metadata, counters, extra=extra).read_bytes()


def expire_lease(api: Api, job_id: int) -> None:
    """Make the job's lease lapse now, as if its host had gone quiet."""
    with session_factory(api.settings.database_url)() as session:
        session.execute(
            update(Job)
            .where(Job.id == job_id)
            .values(lease_expires_at=utcnow() - timedelta(seconds=1))
        )
        session.commit()
