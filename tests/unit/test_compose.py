"""docker-compose.yml runs commands the CLI accepts, and scales as issue 16 asks: the scalable
workers run no periodic tasks (exactly one service does), the API runs several processes."""

from __future__ import annotations

import re

import typer
import yaml
from redline.cli.main import _register_all, app

from tests.support import ROOT

COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def _interpolated(word: str) -> str:
    return re.sub(r"\$\{[A-Z_]+:-([^}]*)\}", r"\1", word)


def parsed(command: list[str]) -> dict:
    """The options the redline CLI parses from a service's command (never run)."""
    _register_all()
    group = typer.main.get_command(app)
    context = group.make_context("redline", [], resilient_parsing=True)
    name, found, rest = group.resolve_command(context, [_interpolated(w) for w in command])
    assert found is not None, name
    return dict(found.make_context(name, list(rest)).params)


def test_every_redline_service_runs_a_command_the_cli_accepts() -> None:
    services = {
        name: parsed(service["command"])
        for name, service in COMPOSE["services"].items()
        if service.get("build") or "<<" in service or name in ("server", "worker", "agent")
    }
    assert services["server"]["workers"] >= 2
    beats = [name for name, options in services.items() if options.get("beat")]
    assert beats == ["alerts"]  # `--scale worker=N` must not start N schedulers
    assert services["worker"]["queues"] == "analysis"
    assert services["alerts"]["queues"] == "alerts"


def test_the_agent_holds_none_of_the_servers_settings_or_storage() -> None:
    agent = COMPOSE["services"]["agent"]
    assert set(agent["environment"]) == {"REDLINE_TOKEN"}  # no database or Redis URL
    assert COMPOSE["services"]["server"]["environment"]["REDLINE_DATABASE_URL"]  # they have it
    assert not [v for v in agent["volumes"] if v.startswith("storage:")]
