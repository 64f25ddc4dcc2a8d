"""The one `redline` command. The server's commands join it when `redline-server` is installed."""

from __future__ import annotations

import importlib
import warnings
from importlib import metadata

import typer

app = typer.Typer(
    name="redline",
    help="Redline: performance regression testing for zenoh components.",
    no_args_is_help=True,
    add_completion=False,
    # Click's plain help: typer's rich renderer costs ~0.3 s at every `--help` and error
    rich_markup_mode=None,
)

# Modules that add commands to `app` through a `register(app)` function; the server's are optional.
_AGENT_COMMANDS = ("redline.cli.run_cmd", "redline.cli.agent_cmd", "redline.cli.ci_cmd")
_SERVER_COMMANDS = (
    "redline.commands.service",
    "redline.commands.up",
    "redline.commands.evaluate",
    "redline.commands.calibrate",
    "redline.commands.compare",
    "redline.commands.model",
    "redline.commands.watch",
)


def server_installed() -> bool:
    """Whether the `redline-server` distribution is installed beside this one."""
    try:
        metadata.distribution("redline-server")
    except metadata.PackageNotFoundError:
        return False
    return True


def command_modules() -> tuple[str, ...]:
    """The modules whose commands `redline` offers here: the server's only where it is installed
    (an import error in one of them is then a real fault, and is not hidden)."""
    return _AGENT_COMMANDS + (_SERVER_COMMANDS if server_installed() else ())


def _register_all() -> None:
    for module in command_modules():
        importlib.import_module(module).register(app)


def main() -> None:
    # platformdirs says so on machines without a login session (containers, CI), once per
    # process, into the output of `redline demo` and every command: nothing a user can act on
    warnings.filterwarnings("ignore", message="XDG_RUNTIME_DIR is not set")
    _register_all()
    app()
