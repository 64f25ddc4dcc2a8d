"""docker-compose.yml runs commands the CLI accepts, and scales as issue 16 asks: the scalable
workers run no periodic tasks (exactly one service does), the API runs several processes, each
agent replica has a work folder of its own, and Redline starts once Postgres and Redis answer."""

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


def test_each_agent_replica_acts_as_a_host_of_its_tokens_pool() -> None:
    """One token for `--scale agent=M`, bound to 'compose-*': each replica names itself after
    its container, inside that pool and apart from the others."""
    import socket

    from redline.cli.agent_cmd import host_name
    from redline.server.core.security import acts_for

    name = host_name(str(parsed(COMPOSE["services"]["agent"]["command"])["name"]))
    assert name == f"compose-{socket.gethostname()}"
    assert acts_for("compose-*", name) and not acts_for("compose-*", "perf-1")


def test_the_agent_holds_none_of_the_servers_settings_or_storage() -> None:
    agent = COMPOSE["services"]["agent"]
    assert set(agent["environment"]) == {"REDLINE_TOKEN"}  # no database or Redis URL
    assert COMPOSE["services"]["server"]["environment"]["REDLINE_DATABASE_URL"]  # they have it
    assert not [v for v in agent["volumes"] if v.startswith("storage:")]


#: the services `docker compose up --scale worker=N --scale agent=M` replicates (issue 16)
SCALED = ("worker", "agent")
#: named volumes every replica shares by design: the storage folder (docs/operations.md)
SHARED_BY_DESIGN = {"storage"}


def _mounts(service: dict) -> list[tuple[str | None, str]]:
    """(source, target) of each volume of ``service``; source None for an anonymous volume."""
    mounts = []
    for volume in service.get("volumes", []):
        if isinstance(volume, dict):
            mounts.append((volume.get("source"), volume["target"]))
            continue
        parts = volume.split(":")
        mounts.append((None, parts[0]) if len(parts) == 1 else (parts[0], parts[1]))
    return mounts


def test_no_scaled_service_shares_a_named_volume_for_its_own_state() -> None:
    for name in SCALED:  # a named volume or a host folder is one folder for every replica
        shared = {source for source, _ in _mounts(COMPOSE["services"][name]) if source}
        assert shared <= SHARED_BY_DESIGN, (name, shared)
    work = str(parsed(COMPOSE["services"]["agent"]["command"])["work"])
    # every replica's clones, recordings and spool in a volume of its own container
    assert _mounts(COMPOSE["services"]["agent"]) == [(None, work)]


def test_redline_waits_for_healthy_postgres_and_redis_and_restarts() -> None:
    services = COMPOSE["services"]
    postgres = services["postgres"]["healthcheck"]["test"]
    # over TCP: a fresh volume's temporary init server answers on the unix socket only
    assert "pg_isready" in postgres and "127.0.0.1" in postgres
    assert "ping" in services["redis"]["healthcheck"]["test"]
    assert "/healthz" in " ".join(services["server"]["healthcheck"]["test"])
    for name in ("server", "worker", "alerts"):
        depends = services[name]["depends_on"]
        assert depends["postgres"]["condition"] == "service_healthy", name
        assert depends["redis"]["condition"] == "service_healthy", name
    assert services["agent"]["depends_on"] == {"server": {"condition": "service_healthy"}}
    for name, service in services.items():
        assert service.get("restart") == "unless-stopped", name
