"""What `redline up` gives the server and the workers it starts: links in alerts lead to the
address it serves (a trial's `redline up --port 8123` mailed links to port 8000)."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from redline.commands.stack import Stack, server_only_variables
from redline.server.core.config import Settings
from redline.worker.messages import webhook_json


@pytest.fixture
def configured(monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    """Database and Redis configured: nothing embedded is started."""
    monkeypatch.setenv("REDLINE_DATABASE_URL", "postgresql+psycopg://unused/never")
    monkeypatch.setenv("REDLINE_REDIS_URL", "redis://unused:1/0")
    monkeypatch.delenv("REDLINE_PUBLIC_URL", raising=False)
    return monkeypatch


def test_alert_links_of_redline_up_lead_to_the_port_it_serves(tmp_path, configured) -> None:
    stack = Stack(tmp_path, port=8123)
    env = stack._service_env()  # what the server and both workers are started with
    assert env["REDLINE_PUBLIC_URL"] == "http://127.0.0.1:8123"
    for name, value in env.items():
        configured.setenv(name, value)
    settings = Settings()  # as a worker started with that environment reads it
    body = webhook_json(
        "regression.opened",
        "uid",
        {"page": "/regressions/2"},
        settings.public_url,
        datetime.now(UTC),
    )
    assert body["alerts"][0]["page_url"] == "http://127.0.0.1:8123/regressions/2"
    assert "REDLINE_PUBLIC_URL" in server_only_variables()  # the agent alone goes without


def test_an_operators_public_url_is_kept_by_redline_up(tmp_path, configured) -> None:
    configured.setenv("REDLINE_PUBLIC_URL", "https://perf.example.org")
    env = Stack(tmp_path, port=8123)._service_env()
    assert env["REDLINE_PUBLIC_URL"] == "https://perf.example.org"
