"""The one `redline` command: agent commands always, the server's when redline-server is there."""

from __future__ import annotations

import subprocess
import sys
from importlib import metadata

import pytest
from redline.cli import main as cli

AGENT_ONLY = """
import importlib.metadata as md, sys
real = md.distribution
def distribution(name):
    if name == "redline-server":
        raise md.PackageNotFoundError(name)
    return real(name)
md.distribution = distribution
for blocked in ("redline.server", "redline.detect", "redline.worker", "scipy", "fastapi"):
    sys.modules[blocked] = None  # as if only redline-agent were installed
from redline.cli.main import main
sys.argv = ["redline", "--help"]
main()
"""


def test_without_the_server_distribution_only_agent_commands_are_offered():
    done = subprocess.run([sys.executable, "-c", AGENT_ONLY], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert " run " in done.stdout and " agent " in done.stdout
    assert " server " not in done.stdout and " compare " not in done.stdout


def test_with_the_server_distribution_every_command_is_offered(monkeypatch: pytest.MonkeyPatch):
    assert cli.server_installed()
    assert set(cli._SERVER_COMMANDS) <= set(cli.command_modules())
    monkeypatch.setattr(metadata, "distribution", _missing)
    assert cli.command_modules() == cli._AGENT_COMMANDS


def _missing(name: str) -> None:
    raise metadata.PackageNotFoundError(name)
