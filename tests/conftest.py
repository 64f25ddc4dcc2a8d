"""Markers by folder, and the fixtures tests of both folders use.

Every test under `tests/unit` is marked `unit`, under `tests/integration` `integration`, so
`-m unit` / `-m "not integration"` select by what a test needs.
"""

from __future__ import annotations

import os
import signal
import tempfile
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
FOLDERS = {HERE / "unit": pytest.mark.unit, HERE / "integration": pytest.mark.integration}
#: the agents the tests start run an execution again after a busy host at most 2 s later: the
#: parallel pass keeps the host busy throughout (three workers on two cores), and at the default
#: wait two reliability tests' jobs outlasted their timeouts (2026-12-07); the wait itself is
#: tested in tests/integration/test_quiet.py
os.environ.setdefault("REDLINE_AGENT_QUIET_WAIT_S", "2")


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C as an interactive shell would deliver it, however the suite was started: a shell
    script that starts the suite in the background (``cmd &``) hands it SIGINT ignored, which
    survives every exec, so the tests of Ctrl-C (to `redline run`, to the runner) would see it
    do nothing. Python's own handler, unlike "ignored", is reset to the default by an exec."""
    signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        for folder, mark in FOLDERS.items():
            if folder in item.path.parents:
                item.add_marker(mark)
    if os.environ.get("PYTEST_XDIST_WORKER"):
        # on xdist's workers, modules with a `slow` test first, each module's tests in their
        # order: the parallel pass hands whole modules to its workers in this order, and the
        # long ones last (most of them late in the alphabet) left one worker finishing them
        # while the others stood idle (the pass's last 8 % of tests took 150 of its 250 s). The
        # serial pass keeps its order: the end-to-end test's CPU verdicts first, on a host no
        # earlier serial test has worked
        slow = {item.path for item in items if item.get_closest_marker("slow") is not None}
        items.sort(key=lambda item: item.path not in slow)


@pytest.fixture
def workspaces_in_tmp_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Workspaces kept after a failure land in the test's own folder, not in /tmp."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
