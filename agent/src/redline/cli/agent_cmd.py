"""`redline agent`: run this machine as a performance host."""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Annotated

import typer
from redline.agent.quiet import QUIET_WAIT_S
from redline.cli.tokens import read_token

if TYPE_CHECKING:
    from redline.agent.daemon import AgentDaemon

log = logging.getLogger("redline.agent")


def agent(
    server: Annotated[str, typer.Option(help="URL of the Redline server", envvar="REDLINE_SERVER")],
    token_file: Annotated[
        Path | None,
        typer.Option(
            help="file holding the API token (scope 'agent'), readable by its owner only; or set "
            "REDLINE_TOKEN. Never on the command line, where every user sees it in ps",
            envvar="REDLINE_TOKEN_FILE",
            dir_okay=False,
        ),
    ] = None,
    name: Annotated[
        str,
        typer.Option(
            help="this host's name; '{hostname}' in it is the machine's (replicas of one "
            "container: 'compose-{hostname}', with a token bound to --host 'compose-*')"
        ),
    ] = socket.gethostname(),
    work: Annotated[Path, typer.Option(help="folder for clones, recordings and the spool")] = Path(
        ".redline-agent"
    ),
    label: Annotated[
        list[str] | None,
        typer.Option(help="host labels (repeatable), among those its token was given"),
    ] = None,
    poll: Annotated[float, typer.Option(help="seconds between retries after an error")] = 2.0,
    wait: Annotated[
        int,
        typer.Option(
            help="long poll: seconds the server may hold a lease "
            "call when no job is queued (0: plain polling)"
        ),
    ] = 20,
    grace: Annotated[
        float,
        typer.Option(help="after SIGTERM, seconds to finish the current job before releasing it"),
    ] = 600.0,
    disturbed_retries: Annotated[
        int,
        typer.Option(
            min=0,
            envvar="REDLINE_DISTURBED_RETRIES",
            help="times an execution is run again when the host was busy during a phase "
            "(other load over REDLINE_DISTURBED_CPU_PERCENT)",
        ),
    ] = 2,
    quiet_wait: Annotated[
        float,
        typer.Option(
            min=0,
            envvar="REDLINE_AGENT_QUIET_WAIT_S",
            help="before such a run again, seconds to wait at most for the host to be quiet "
            "(0: at once)",
        ),
    ] = QUIET_WAIT_S,
    allow_file_repos: Annotated[
        bool,
        typer.Option(
            help="fetch jobs' repositories from local paths and file:// URLs too (one-machine "
            "setups); otherwise only https, ssh and git",
            envvar="REDLINE_ALLOW_FILE_REPOS",
        ),
    ] = False,
) -> None:
    """Pull jobs from the server, run them, upload the recordings.

    SIGTERM or SIGINT: finish the current job, then stop; a second signal, or the end of the grace
    period, releases the job back to the queue instead. Spooled recordings wait for the next start.
    """
    from redline.agent.client import Refused, ServerClient
    from redline.agent.daemon import AgentDaemon, AgentStopping

    token = read_token(token_file)
    # the token is the agent's: the builds and components it runs (whose output reaches the
    # server's pages) inherit its environment, and must not find it there
    os.environ.pop("REDLINE_TOKEN", None)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s agent %(levelname)s %(message)s")
    daemon = AgentDaemon(
        ServerClient(server, token, host_name(name)),
        work.resolve(),
        labels=label or [],
        poll_interval=poll,
        long_poll=wait,
        allow_file_repos=allow_file_repos,
        disturbed_retries=disturbed_retries,
        quiet_wait=quiet_wait,
    )
    _Signals(daemon, grace, AgentStopping).install()
    try:
        daemon.run_forever()
    except AgentStopping:
        log.info("agent stopped")
    except Refused as exc:  # its token will not do: say why and stop, not retry for good
        typer.echo(str(exc), err=True)
        raise typer.Exit(1) from None


def host_name(template: str) -> str:
    """The name the agent acts as: ``template`` with '{hostname}' the machine's."""
    return template.replace("{hostname}", socket.gethostname())


class _Signals:
    """First signal: finish, then stop. Second signal or grace period over: release and stop."""

    def __init__(self, daemon: AgentDaemon, grace: float, stopping: type[BaseException]) -> None:
        self.daemon, self.grace, self.stopping = daemon, grace, stopping
        self.count = 0

    def install(self) -> None:
        signal.signal(signal.SIGTERM, self.handle)
        signal.signal(signal.SIGINT, self.handle)

    def handle(self, signum: int, _frame: FrameType | None) -> None:
        self.count += 1
        self.daemon.stop.set()
        if self.daemon.waiting:  # no job: leave the long poll now
            raise self.stopping(f"signal {signum}")
        if self.daemon.current_job is None:  # between jobs or delivering: that ends by itself
            log.info("signal %d: stopping after the recording in hand is delivered", signum)
            return
        if self.count > 1:
            raise self.stopping(f"signal {signum}")
        log.info(
            "signal %d: finishing job %s (at most %.0fs), then stopping",
            signum,
            self.daemon.current_job,
            self.grace,
        )
        timer = threading.Timer(self.grace, os.kill, (os.getpid(), signal.SIGTERM))
        timer.daemon = True
        timer.start()


def register(app: typer.Typer) -> None:
    app.command("agent")(agent)
