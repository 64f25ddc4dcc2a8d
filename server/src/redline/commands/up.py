"""`redline up` and `redline demo`: the whole service on this machine.

The stack (embedded Postgres and Redis), httpx and rich are imported when a command runs, not
here: every `redline` command line imports this module to build the CLI.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import typer

if TYPE_CHECKING:
    from redline.commands.stack import Stack
    from rich.console import Console

#: what a new user does next, said once the service is up
NEXT = (
    "your own component: register it with the admin token (POST /api/v1/components, its repo a "
    "git URL or a local path), report each commit with the ci token (redline ci report) "
    "and wait for its verdict with `redline ci wait`: docs/ci.md; its tests: "
    "docs/writing-tests.md"
)

DataOption = typer.Option(
    Path(".redline"), "--data", help="folder for the database, recordings, logs"
)
PortOption = typer.Option(8080, "--port", help="port of the API server and web UI")


def _serve(
    console: Console,
    data: Path,
    port: int,
    then: Callable[[Stack, threading.Event], None] | None = None,
) -> None:
    """Start the stack, run ``then`` (which must return soon after the stop event is set),
    and supervise until Ctrl-C or SIGTERM."""
    import httpx
    from redline.agent.interrupts import set_on_signals
    from redline.commands.stack import Stack, StackError

    stack = Stack(data.resolve(), port)
    stop = threading.Event()

    set_on_signals(stop, signal.SIGINT, signal.SIGTERM)
    try:
        stack.start()
        console.print(f"Redline is up at [bold]{stack.url}[/bold]")
        console.print(f"admin token: in {stack.data / 'admin-token'} (readable by you only)")
        stack.token("ci", "ci")  # what CI reports revisions and waits for verdicts with
        console.print(f"ci token: in {stack.data / 'ci-token'} (readable by you only)")
        console.print(f"logs: {stack.data / 'logs'}   stop with Ctrl-C")
        console.print(NEXT, soft_wrap=True)
        if then is not None:
            then(stack, stop)
        while not stop.wait(1.0):
            stack.check_children()
    except (StackError, httpx.HTTPError, TimeoutError) as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(1) from exc
    finally:
        started = bool(stack.children) or stack.embedded is not None  # a refused start: none
        if started:
            console.print("stopping…")
        stack.stop()
        if started:
            console.print("stopped: no process of it is left")


def up(data: Path = DataOption, port: int = PortOption) -> None:
    """Run the server, a worker and a local agent, on embedded Postgres and Redis unless
    REDLINE_DATABASE_URL / REDLINE_REDIS_URL are set."""
    from rich.console import Console

    _serve(Console(), data, port)


def demo(data: Path = DataOption, port: int = PortOption) -> None:
    """`redline up`, plus an example component with three revisions (one a deliberate CPU
    regression) submitted as CI would; shows the trend charts and the detected change."""
    import httpx
    from redline.commands import demo as example
    from rich.console import Console
    from rich.markup import escape

    console = Console()

    def show(stack: Stack, stop: threading.Event) -> None:
        revisions = example.make_history(stack.data / "demo-repo")
        ci_token = stack.token("ci", "ci")
        example.submit(stack.url, stack.admin_token, ci_token, stack.data / "demo-repo", revisions)
        console.print(
            f"submitted {len(revisions)} revisions of {example.COMPONENT}; "
            "the local agent runs them one by one"
        )
        if not example.wait_for_results(stack.url, console.print, stop=stop):
            return  # stopped before the results were in
        flagged = httpx.get(
            f"{stack.url}/api/v1/components/{example.COMPONENT}/detections",
            params={"method": "ks", "limit": 10_000},
        ).json()
        for change in reversed([d for d in flagged if d["flagged"]]):  # oldest revision first
            kind = example.change_kind(change)
            colour = {"regression": "red", "not confirmed": "dim"}.get(kind, "yellow")
            # one line each, however narrow the terminal (or a log file: no terminal at all)
            console.print(
                f"[{colour}]{kind}[/{colour}] {escape(example.change_line(change))}",
                soft_wrap=True,
            )
        newest = httpx.get(
            f"{stack.url}/api/v1/components/{example.COMPONENT}/detections",
            params={"revision": revisions[-1].title, "method": "ks"},
        ).json()
        if why := example.unmarked(newest):
            console.print(f"[yellow]{escape(why)}[/yellow]", soft_wrap=True)
        console.print(f"trend charts: [bold]{stack.url}/components/{example.COMPONENT}[/bold]")

    _serve(console, data, port, then=show)


def register(app: typer.Typer) -> None:
    app.command("up")(up)
    app.command("demo")(demo)
