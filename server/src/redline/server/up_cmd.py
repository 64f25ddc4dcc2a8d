"""`redline up` and `redline demo`: the whole service on this machine."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from pathlib import Path
from types import FrameType

import httpx
import typer
from redline.server.stack import Stack, StackError
from rich.console import Console

console = Console()
DataOption = typer.Option(
    Path(".redline"), "--data", help="folder for the database, recordings, logs"
)
PortOption = typer.Option(8080, "--port", help="port of the API server and web UI")


def _serve(data: Path, port: int, then: Callable[[Stack], None] | None = None) -> None:
    stack = Stack(data.resolve(), port)
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        stack.start()
        console.print(f"Redline is up at [bold]{stack.url}[/bold]")
        console.print(f"admin token: {stack.admin_token}  (also in {stack.data / 'admin-token'})")
        console.print(f"logs: {stack.data / 'logs'}   stop with Ctrl-C")
        if then is not None:
            then(stack)
        while not stop.wait(1.0):
            stack.check_children()
    except (StackError, httpx.HTTPError, TimeoutError) as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(1) from exc
    finally:
        console.print("stopping…")
        stack.stop()


def up(data: Path = DataOption, port: int = PortOption) -> None:
    """Run the server, a worker and a local agent, on embedded Postgres and Redis unless
    REDLINE_DATABASE_URL / REDLINE_REDIS_URL are set."""
    _serve(data, port)


def demo(data: Path = DataOption, port: int = PortOption) -> None:
    """`redline up`, plus an example component with three revisions (one a deliberate CPU
    regression) submitted as CI would; shows the trend charts and the detected change."""
    from redline.server import demo as example

    def show(stack: Stack) -> None:
        revisions = example.make_history(stack.data / "demo-repo")
        ci_token = stack.token("ci", "ci")
        example.submit(stack.url, stack.admin_token, ci_token, stack.data / "demo-repo", revisions)
        console.print(
            f"submitted {len(revisions)} revisions of {example.COMPONENT}; "
            "the local agent runs them one by one"
        )
        example.wait_for_results(stack.url, console.print)
        changes = httpx.get(f"{stack.url}/api/v1/components/{example.COMPONENT}/changes").json()
        for change in (c for c in changes if c.get("flagged")):
            console.print(
                f"[yellow]change[/yellow] {change['revision']}: {change['series']} "
                f"effect {change['effect']:+.0%} (KS D={change['score']:.2f})"
            )
        console.print(f"trend charts: [bold]{stack.url}/components/{example.COMPONENT}[/bold]")

    _serve(data, port, then=show)


def register(app: typer.Typer) -> None:
    app.command("up")(up)
    app.command("demo")(demo)
