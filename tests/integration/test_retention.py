"""Retention: raw recordings older than the age are deleted, summaries kept, pruning recorded."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import pytest
from redline.server.db import session_factory
from redline.server.models import Execution, Summary, utcnow
from redline.worker.retention import prune_recordings, raw_files
from sqlalchemy import func, select, update

from tests.support import ROOT
from tests.support.api import Api, api_with
from tests.support.servers import Services


@pytest.fixture
def api(services: Services, tmp_path: Path) -> Iterator[Api]:
    with api_with(services, tmp_path, retention_days=30) as api:
        api.post("/api/v1/components", "admin", {"name": "builder"}).raise_for_status()
        yield api


def run(api: Api, revision: str, key: str, base: float, age_days: int) -> int:
    body = {
        "component": "builder",
        "revision": revision,
        "sort_key": key,
        "results": [
            {"case": "build", "counter": "cpu", "values": [base + i % 5 for i in range(40)]}
        ],
    }
    execution_id = api.post("/api/v1/import/results", "ci", body).json()["execution_id"]
    with session_factory(api.settings.database_url)() as session:
        session.execute(
            update(Execution)
            .where(Execution.id == execution_id)
            .values(created=utcnow() - timedelta(days=age_days))
        )
        session.commit()
    return execution_id


def paths_of(api: Api, execution_id: int) -> list[Path]:
    with session_factory(api.settings.database_url)() as session:
        return raw_files(session.get_one(Execution, execution_id).recording_path)


def test_old_raw_files_are_deleted_and_summaries_kept(api: Api):
    old, new = run(api, "r1", "1", 10.0, age_days=40), run(api, "r2", "2", 20.0, age_days=1)
    assert all(path.exists() for path in paths_of(api, old) + paths_of(api, new))
    assert prune_recordings(api.settings.database_url, days=30) == 1
    assert not any(path.exists() for path in paths_of(api, old))
    assert all(path.exists() for path in paths_of(api, new))
    detail = api.client.get(f"/api/v1/executions/{old}").json()
    assert detail["recording_pruned_at"] is not None and detail["series"] == 1
    with session_factory(api.settings.database_url)() as session:
        assert session.scalar(select(func.count()).select_from(Summary)) == 2
    assert prune_recordings(api.settings.database_url, days=30) == 0  # idempotent


def test_compare_after_pruning_uses_the_sketch_and_says_so(api: Api):
    run(api, "r1", "1", 10.0, age_days=40)
    run(api, "r2", "2", 20.0, age_days=1)
    prune_recordings(api.settings.database_url, days=30)
    row = api.client.get("/api/v1/components/builder/compare?base=r1&candidate=r2").json()[
        "series"
    ][0]
    assert row["exact"] is False and row["baseline"]["n"] == 32
    assert row["change"] == pytest.approx(10 / 12, rel=0.05) and row["ks_statistic"] == 1.0


def test_cli_runs_retention_once(api: Api):
    old = run(api, "r1", "1", 10.0, age_days=100)
    env = {
        **os.environ,
        "REDLINE_DATABASE_URL": api.settings.database_url,
        "REDLINE_RETENTION_DAYS": "60",
    }
    done = subprocess.run(
        [str(Path(sys.executable).parent / "redline"), "retention", "run"],
        env=env,
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert done.returncode == 0, done.stderr
    assert "1 executions older than 60 days" in done.stdout
    assert not paths_of(api, old)[0].exists()
