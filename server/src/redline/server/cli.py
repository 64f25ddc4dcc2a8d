"""The server's `redline` commands: server, worker, migrate, token create.

All read their configuration from ``REDLINE_*`` environment variables (see core/config.py).
"""

from __future__ import annotations

from typing import Annotated

import typer
from redline.server.core.config import get_settings

token_app = typer.Typer(help="Manage API tokens.", no_args_is_help=True)


def migrate_cmd() -> None:
    """Upgrade the database (REDLINE_DATABASE_URL) to the newest schema."""
    from redline.server.db import migrate

    settings = get_settings()
    migrate(settings.database_url, settings.migrations_dir)
    typer.echo("database is up to date")


def server_cmd(
    host: Annotated[str, typer.Option(help="interface to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port")] = 8000,
) -> None:
    """Migrate the database, then serve the API and the UI."""
    import uvicorn
    from redline.server.app import create_app
    from redline.server.db import migrate

    settings = get_settings()
    migrate(settings.database_url, settings.migrations_dir)
    uvicorn.run(create_app(settings), host=host, port=port)


def worker_cmd(
    concurrency: Annotated[int, typer.Option(help="worker processes")] = 1,
    loglevel: Annotated[str, typer.Option(help="Celery log level")] = "INFO",
) -> None:
    """Run a Celery worker that ingests recordings and detects changes."""
    from redline.worker.app import celery_app

    celery_app.worker_main(["worker", f"--concurrency={concurrency}", f"--loglevel={loglevel}"])


@token_app.command("create")
def token_create(
    name: Annotated[str, typer.Argument(help="who or what the token is for")],
    scopes: Annotated[str, typer.Option(help="comma-separated: ci, agent, read, admin")],
) -> None:
    """Create a token and print it; it is stored only as a hash and cannot be shown again."""
    from redline.server.core.security import parse_scopes
    from redline.server.db import session_factory
    from redline.server.services.tokens import create_token

    try:
        parse_scopes(scopes)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--scopes") from None
    with session_factory(get_settings().database_url)() as session:
        typer.echo(create_token(session, name, scopes))


def register(app: typer.Typer) -> None:
    app.command("server")(server_cmd)
    app.command("worker")(worker_cmd)
    app.command("migrate")(migrate_cmd)
    app.add_typer(token_app, name="token")
