"""Resource-usage models through the API on real Postgres: a training request validated at once,
the model fitted by the worker's task from the named executions' recordings, listed with its
metrics and provenance, its file downloaded and usable; run-time alerts reported by an agent
token; and the bad input that must be refused or fail naming its cause."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from redline.predict.dataset import dataset, read_run
from redline.predict.model import ModelFile
from redline.server.db import session_factory
from redline.server.models import Execution, Job, JobState, Revision
from redline.worker.training import train_model
from sqlalchemy import select

from tests.support.api import api_with
from tests.support.predict import record

BASE = "/api/v1/components/builder"


@pytest.fixture
def api(services, tmp_path):
    with api_with(services, tmp_path) as driver:
        driver.component()
        yield driver


def executed(api, tmp_path: Path, title: str, legs: list[int], **extra) -> int:
    """A revision whose one job ran: its recording (a leg-processing component's) stored."""
    api.revision(title, title.removeprefix("r"))
    path = record(tmp_path / f"{title}.mcap", legs, seed=len(title) + legs[0], **extra)
    with session_factory(api.settings.database_url)() as session:
        revision = session.scalar(select(Revision).where(Revision.title == title))
        (job,) = session.scalars(select(Job).where(Job.revision_id == revision.id))
        job.state = JobState.done
        execution = Execution(
            job_id=job.id,
            revision_id=revision.id,
            recording_path=str(path),
            sha256=hashlib.sha256(path.read_bytes()).hexdigest(),
            size=path.stat().st_size,
        )
        session.add(execution)
        session.commit()
        return execution.id


def train(api, body: dict) -> dict:
    answer = api.post(f"{BASE}/models", "admin", body)
    assert answer.status_code == 202, answer.text
    assert answer.json()["state"] == "queued"
    train_model(api.settings.database_url, api.settings.storage_dir, answer.json()["id"])
    return api.client.get(f"{BASE}/models/{answer.json()['id']}").json()


def test_a_model_is_trained_from_named_executions_and_its_file_predicts(api, tmp_path):
    first = executed(api, tmp_path, "r1", [1, 4, 7, 10, 13])
    executed(api, tmp_path, "r2", [2, 5, 8, 11, 14])
    model = train(api, {"revisions": ["r2"], "executions": [first]})
    assert model["state"] == "done", model["error"]
    assert model["process"] == "builder"
    assert model["provenance"]["revisions"] == ["r1", "r2"]
    assert sorted(model["provenance"]["executions"]) == [1, 2]
    assert model["provenance"]["versions"]["scikit-learn"]
    assert model["metrics"]["cpu_percent"]["cv_ratio"] < 0.5
    assert model["metrics"]["cpu_percent"]["threshold"] > 0
    listed = api.client.get(f"{BASE}/models").json()
    assert [m["id"] for m in listed] == [model["id"]]
    download = api.client.get(model["file"])
    assert download.status_code == 200
    path = tmp_path / "downloaded.joblib"
    path.write_bytes(download.content)
    unseen = dataset([read_run(record(tmp_path / "new.mcap", [3, 6, 9], seed=9))])
    assert ModelFile.load(path).score(unseen)["cpu_percent"]["ratio"] < 0.5


def test_requests_are_checked_at_once_and_training_failures_say_why(api, tmp_path):
    executed(api, tmp_path, "r1", [3])  # one parameter set: nothing to cross-validate
    executed(api, tmp_path, "r2", [1, 5], traffic=False)
    for scope in ("ci", "triage", "read", "agent"):
        assert api.post(f"{BASE}/models", scope, {}).status_code == 403
    unknown = api.post(f"{BASE}/models", "admin", {"revisions": ["r1", "nope"], "executions": [99]})
    assert unknown.status_code == 422
    assert "nope" in unknown.text and "99" in unknown.text
    # an id no database holds is named, not "a value in the request cannot be stored"
    huge = api.post(f"{BASE}/models", "admin", {"executions": [2**64]})
    assert huge.status_code == 422 and huge.json()["detail"][0]["loc"][-2] == "executions"
    typo = api.post(f"{BASE}/models", "admin", {"revision": ["r1"]})
    assert typo.status_code == 422 and "revision" in typo.text
    assert api.post("/api/v1/components/nobody/models", "admin", {}).status_code == 404
    small = train(api, {"revisions": ["r1"]})
    assert small["state"] == "failed" and "too little to train on" in small["error"]
    silent = train(api, {"revisions": ["r2"]})
    assert silent["state"] == "failed" and "holds no traffic" in silent["error"]
    assert api.client.get(f"{BASE}/models/{silent['id']}/file").status_code == 404
    assert api.client.get(f"{BASE}/models/999").status_code == 404


def test_runtime_alerts_are_reported_with_an_agent_token_and_listed(api):
    alert = {"target": "cpu_percent", "started": True, "residual": 75.0, "threshold": 9.5}
    assert api.post(f"{BASE}/runtime-alerts", "ci", alert).status_code == 403
    made = api.post(f"{BASE}/runtime-alerts", "agent", {**alert, "host": "robot1", "step": 14})
    assert made.status_code == 201, made.text
    bad = api.post(f"{BASE}/runtime-alerts", "agent", {**alert, "residual": "NaN"})
    assert bad.status_code == 422
    ghost = api.post(f"{BASE}/runtime-alerts", "agent", {**alert, "model": 42})
    assert ghost.status_code == 404 and "no model 42" in ghost.text
    (listed,) = api.client.get(f"{BASE}/runtime-alerts").json()
    assert (listed["host"], listed["residual"], listed["started"]) == ("robot1", 75.0, True)


def test_a_runtime_alert_comes_from_its_tokens_host(api):
    """A robot's watcher reports for its own host: one naming another is refused, one naming
    none is recorded as the token's."""
    alert = {"target": "cpu_percent", "started": True, "residual": 75.0, "threshold": 9.5}
    robot = api.headers("agent", "robot1")
    forged = api.client.post(
        f"{BASE}/runtime-alerts", json={**alert, "host": "robot2"}, headers=robot
    )
    assert forged.status_code == 403 and "'robot1'" in forged.text and "'robot2'" in forged.text
    made = api.client.post(f"{BASE}/runtime-alerts", json=alert, headers=robot)
    assert made.status_code == 201 and made.json()["host"] == "robot1"
    (listed,) = api.client.get(f"{BASE}/runtime-alerts").json()
    assert listed["host"] == "robot1"


def test_the_pages_show_models_with_their_chart_and_runtime_alerts(api, tmp_path):
    first = executed(api, tmp_path, "r1", [1, 4, 7, 10, 13])
    model = train(api, {"executions": [first]})
    api.post(
        f"{BASE}/runtime-alerts",
        "agent",
        {"target": "cpu_percent", "started": True, "residual": 75.0, "threshold": 9.5},
    )
    page = api.client.get("/components/builder").text
    assert f'href="/components/builder/models/{model["id"]}"' in page
    assert "cpu_percent fault" in page and "+75" in page
    detail = api.client.get(f"/components/builder/models/{model['id']}")
    assert detail.status_code == 200 and "alarm threshold" in detail.text
    figures = detail.text.split('id="figure-data">', 1)[1].split("</script>", 1)[0]
    (cpu, _) = json.loads(figures)
    assert [trace["name"] for trace in cpu["data"]] == ["measured", "predicted"]
    assert len(cpu["data"][0]["y"]) == len(cpu["data"][1]["y"]) > 10
    assert api.client.get("/components/builder/models/999").status_code == 404
