"""The whole path on real Postgres, Redis, zenoh and a real Celery worker.

CI report → job → agent (checkout, build, run with monitor and recorder) → MCAP upload →
ingest → KS detection → API and trend page. The example's history has a baseline, a revision
that does not touch the code's work, and one doing three times the work per leg pair.
"""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import pytest

from redline.server import demo
from redline.server.stack import Stack
from tests.conftest import Services, fresh_database

pytestmark = pytest.mark.integration

CPU = "cpu_percent"


@pytest.fixture
def stack(services: Services, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Stack:
    from redline.agent.network import free_port

    database_url, _ = fresh_database(services.database_url)
    monkeypatch.setenv("REDLINE_DATABASE_URL", database_url)
    monkeypatch.setenv("REDLINE_REDIS_URL", services.redis_url)
    monkeypatch.setenv("REDLINE_QUEUE", f"e2e-{tmp_path.name}")
    running = Stack(tmp_path / "data", free_port())
    try:
        running.start()
        yield running
    finally:
        running.stop()


def _cpu_changes(changes: list[dict], revision: str) -> list[dict]:
    return [c for c in changes if c["revision"] == revision and c["series"]["counter"] == CPU]


def test_tripled_work_is_flagged_by_ks_and_unchanged_code_is_not(stack: Stack, tmp_path: Path):
    repo = tmp_path / "objectbuilder-repo"
    base, unchanged, regressed = demo.make_history(repo)
    demo.submit(stack.url, stack.admin_token, stack.token("ci", "ci"), repo,
                [base, unchanged, regressed])

    revisions = demo.wait_for_results(stack.url, print, timeout=600)
    assert [r["title"] for r in revisions] == [base.title, unchanged.title, regressed.title]
    assert all(r["state"] == "done" for r in revisions), revisions

    changes = httpx.get(f"{stack.url}/api/v1/components/objectbuilder/changes").json()
    flagged = [c for c in _cpu_changes(changes, regressed.title) if c["flagged"]]
    assert flagged, json.dumps(_cpu_changes(changes, regressed.title), indent=1)
    assert all(c["effect"] > 0.5 for c in flagged)  # three times the work: far more CPU
    assert not [c for c in _cpu_changes(changes, unchanged.title) if c["flagged"]]
    assert not _cpu_changes(changes, base.title)  # the first revision has no baseline

    page = httpx.get(f"{stack.url}/components/objectbuilder")
    assert page.status_code == 200 and "plotly" in page.text
    assert httpx.get(f"{stack.url}/static/plotly.min.js").status_code == 200
