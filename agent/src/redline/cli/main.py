"""The one `redline` command. The server's commands join it when `redline-server` is installed."""

from __future__ import annotations

import importlib

import typer

app = typer.Typer(
    name="redline",
    help="Redline: performance regression testing for zenoh components.",
    no_args_is_help=True,
    add_completion=False,
)

# Modules that add commands to `app` through a `register(app)` function; the server's are optional.
_AGENT_COMMANDS = ("redline.cli.run_cmd", "redline.cli.agent_cmd")
_SERVER_COMMANDS = ("redline.server.cli", "redline.server.up_cmd", "redline.detect.evaluate_cmd",
                    "redline.detect.compare_cmd")


def _register_all() -> None:
    for module in _AGENT_COMMANDS:
        importlib.import_module(module).register(app)
    for module in _SERVER_COMMANDS:
        try:
            loaded = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.startswith("redline.server"):
                continue  # redline-server is not installed: agent commands only
            raise
        loaded.register(app)


def main() -> None:
    _register_all()
    app()
