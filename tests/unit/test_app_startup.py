"""The server loads scipy.stats beside its first requests, not in their way (`redline.server.app`):
a trial's first compare page took 1.7 s, most of it that import, the later ones under 0.2 s."""

from __future__ import annotations

import subprocess
import sys

PROBE = """
import sys, time
from fastapi.testclient import TestClient
from redline.server.app import create_app
from redline.server.core.config import Settings

assert "scipy.stats" not in sys.modules, "imported by the app itself: the warm-up proves nothing"
nowhere = Settings(database_url="postgresql+psycopg://u@127.0.0.1:1/x", redis_url="redis://127.0.0.1:1")
with TestClient(create_app(nowhere)):
    deadline = time.monotonic() + 30
    while "scipy.stats" not in sys.modules and time.monotonic() < deadline:
        time.sleep(0.05)
    print("warm" if "scipy.stats" in sys.modules else "cold")  # no request, no import here
"""


def test_the_server_loads_the_statistics_at_startup_without_a_request() -> None:
    done = subprocess.run(
        [sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "warm"


def test_a_webhook_secret_short_enough_to_guess_is_warned_of_at_start(caplog) -> None:
    """A review: a component's own secret must have 16 characters, the setting had no minimum.
    Refusing it would stop a running deployment at its next restart: the start says so
    instead, and the secret itself appears in no log."""
    from redline.server.app import create_app
    from redline.server.core.config import Settings

    nowhere = {"database_url": "postgresql+psycopg://u@127.0.0.1:1/x", "redis_url": "redis://x:1"}
    with caplog.at_level("WARNING", logger="redline.server.app"):
        create_app(Settings(**nowhere, webhook_secret="hunter2"))
    (warning,) = [
        r.getMessage() for r in caplog.records if "REDLINE_WEBHOOK_SECRET" in r.getMessage()
    ]
    assert "has 7 characters" in warning and "16 or more" in warning
    assert "hunter2" not in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING", logger="redline.server.app"):
        create_app(Settings(**nowhere, webhook_secret="a-secret-long-enough-to-keep"))
        create_app(Settings(**nowhere))  # none: webhooks need a component's own
    assert "REDLINE_WEBHOOK_SECRET" not in caplog.text
