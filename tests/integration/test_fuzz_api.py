"""The API fuzzed from its own OpenAPI document (schemathesis): whatever it is sent, never a 5xx.

Bounded and repeatable: at most 25 examples per operation, derandomized (a fixed seed), against
the real app on real Postgres and Redis, with an admin token so the fuzzer gets past the door.
"""

from __future__ import annotations

import uuid
from pathlib import Path

import pytest
import schemathesis
from fastapi import FastAPI
from hypothesis import HealthCheck, Phase, given, settings
from redline.server.app import create_app
from redline.server.core.config import Settings
from redline.server.db import migrate, session_factory
from redline.server.services.tokens import issue_token
from schemathesis.checks import not_a_server_error

from tests.support.servers import Services, fresh_database

pytestmark = pytest.mark.slow

MAX_EXAMPLES = 25
#: no fuzzed long poll may hold the run: the lease waits at most this long here
MAX_WAIT_S = 1


@pytest.fixture(scope="module")
def fuzz_app(services: Services, tmp_path_factory: pytest.TempPathFactory) -> FastAPI:
    database_url, _ = fresh_database(services.database_url)
    migrate(database_url)
    storage = tmp_path_factory.mktemp("fuzz") / "storage"
    app_settings = Settings(
        database_url=database_url,
        redis_url=services.redis_url,
        storage_dir=Path(storage),
        queue=f"fuzz-{uuid.uuid4().hex[:8]}",
        max_upload_bytes=1_000_000,
    )
    app = create_app(app_settings)
    with session_factory(database_url)() as session:
        app.state.fuzz_token = issue_token(session, "fuzz-admin", "admin")[1]
    return app


def _fuzz(operation: schemathesis.APIOperation, token: str) -> None:
    @given(operation.as_strategy())
    @settings(
        max_examples=MAX_EXAMPLES,
        derandomize=True,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
        phases=[Phase.explicit, Phase.generate],
    )
    def examples(case: schemathesis.Case) -> None:
        if case.query and isinstance(case.query.get("wait"), int):
            case.query["wait"] = min(case.query["wait"], MAX_WAIT_S)
        case.call_and_validate(
            headers={"Authorization": f"Bearer {token}"}, checks=[not_a_server_error]
        )

    examples()


def test_no_operation_answers_5xx(fuzz_app: FastAPI) -> None:
    schema = schemathesis.openapi.from_asgi("/openapi.json", fuzz_app)
    failures = []
    for result in schema.get_all_operations():
        operation = result.ok()
        try:
            _fuzz(operation, fuzz_app.state.fuzz_token)
        except Exception as exc:  # every operation is fuzzed; all their 5xx are reported
            failures.append(f"{operation.method.upper()} {operation.path}: {exc}")
    assert not failures, "\n\n".join(failures)
