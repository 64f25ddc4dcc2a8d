"""`redline agent`: run this machine as a performance host."""

from __future__ import annotations

import logging
import signal
import socket
from pathlib import Path
from types import FrameType

import typer


def agent(
    server: str = typer.Option(..., help="URL of the Redline server", envvar="REDLINE_SERVER"),
    token: str = typer.Option(..., help="API token with scope 'agent'", envvar="REDLINE_TOKEN"),
    name: str = typer.Option(socket.gethostname(), help="this host's name on the server"),
    work: Path = typer.Option(Path(".redline-agent"), help="folder for clones and recordings"),
    label: list[str] = typer.Option([], help="host labels (repeatable)"),
    poll: float = typer.Option(2.0, help="seconds between polls when no job is queued"),
) -> None:
    """Pull jobs from the server, run them, upload the recordings. Stops on SIGINT/SIGTERM."""
    from redline.agent.client import ServerClient
    from redline.agent.daemon import AgentDaemon

    logging.basicConfig(level=logging.INFO, format="%(asctime)s agent %(levelname)s %(message)s")
    daemon = AgentDaemon(ServerClient(server, token, name), work.resolve(), labels=label,
                         poll_interval=poll)

    def stop(signum: int, _frame: FrameType | None) -> None:
        logging.getLogger("redline.agent").info("signal %d: finishing the current job, then stopping", signum)
        daemon.stop.set()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    daemon.run_forever()


def register(app: typer.Typer) -> None:
    app.command("agent")(agent)
