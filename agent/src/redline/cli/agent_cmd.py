"""`redline agent`: run this machine as a performance host."""

from __future__ import annotations

import logging
import signal
import socket
from pathlib import Path
from types import FrameType
from typing import Annotated

import typer


def agent(
    server: Annotated[str, typer.Option(help="URL of the Redline server",
                                        envvar="REDLINE_SERVER")],
    token: Annotated[str, typer.Option(help="API token with scope 'agent'",
                                       envvar="REDLINE_TOKEN")],
    name: Annotated[str, typer.Option(help="this host's name")] = socket.gethostname(),
    work: Annotated[Path, typer.Option(help="folder for clones and recordings")] = Path(
        ".redline-agent"),
    label: Annotated[list[str] | None, typer.Option(help="host labels (repeatable)")] = None,
    poll: Annotated[float, typer.Option(help="seconds between polls with no job")] = 2.0,
) -> None:
    """Pull jobs from the server, run them, upload the recordings. Stops on SIGINT/SIGTERM."""
    from redline.agent.client import ServerClient
    from redline.agent.daemon import AgentDaemon

    logging.basicConfig(level=logging.INFO, format="%(asctime)s agent %(levelname)s %(message)s")
    daemon = AgentDaemon(ServerClient(server, token, name), work.resolve(), labels=label or [],
                         poll_interval=poll)

    def stop(signum: int, _frame: FrameType | None) -> None:
        logging.getLogger("redline.agent").info(
            "signal %d: finishing the current job, then stopping", signum)
        daemon.stop.set()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    daemon.run_forever()


def register(app: typer.Typer) -> None:
    app.command("agent")(agent)
