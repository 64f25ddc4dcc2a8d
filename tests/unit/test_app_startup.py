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
