"""The server's `redline` commands: server, worker, migrate, token, user, retention.

All read their configuration from ``REDLINE_*`` environment variables (see core/config.py).
Everything beyond typer is imported inside the commands: every `redline` command line imports
this module to build the CLI.
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, ParamSpec, TypeVar

import typer

if TYPE_CHECKING:
    from redline.server.core.config import Settings

token_app = typer.Typer(help="Manage API tokens.", no_args_is_help=True)
retention_app = typer.Typer(help="Raw recordings' retention.", no_args_is_help=True)
user_app = typer.Typer(help="People who sign in to the pages.", no_args_is_help=True)


def _settings() -> Settings:
    from redline.server.core.config import get_settings  # pydantic-settings: ~0.4 s to import

    return get_settings()


#: the data folder of the `redline up` whose services the commands use when none is configured
DATA_VARIABLE = "REDLINE_DATA"


def _local_stack() -> None:
    """Without ``REDLINE_DATABASE_URL``, the embedded database and Redis of the `redline up` on
    this machine whose data folder is ``REDLINE_DATA`` (default ``.redline``): what the Quick
    start's `redline user create` needs (a trial got "database "redline" does not exist")."""
    from redline.commands.embedded import read_services

    if os.environ.get("REDLINE_DATABASE_URL"):
        return
    data = Path(os.environ.get(DATA_VARIABLE) or ".redline")
    found = read_services(data)
    if "REDLINE_DATABASE_URL" in found:
        for name, value in found.items():
            os.environ.setdefault(name, value)
        # said, so that it is no surprise which database the command changed
        typer.echo(f"(using the database of the `redline up` whose data is in {data})", err=True)
    else:  # said, not silently taken: a trial's command, run elsewhere, reached another Postgres
        from sqlalchemy.engine import make_url

        default = make_url(_settings().database_url).render_as_string(hide_password=True)
        typer.echo(
            f"(no REDLINE_DATABASE_URL, and no `redline up` data in {data}: the database "
            f"{default})",
            err=True,
        )


SHUTDOWN_GRACE_S = 2  # seconds requests in flight get when the server is asked to stop
P = ParamSpec("P")
R = TypeVar("R")


def needs_database(command: Callable[P, R]) -> Callable[P, R]:
    """A command that talks to the database (the configured one, else that of the `redline up`
    running here): an unreachable one is a message, not a traceback."""

    @functools.wraps(command)
    def run(*args: P.args, **kwargs: P.kwargs) -> R:
        from sqlalchemy.exc import InterfaceError, OperationalError

        _local_stack()
        try:
            return command(*args, **kwargs)
        except (OperationalError, InterfaceError) as exc:
            reason = (str(exc.orig or exc).strip().splitlines() or ["unreachable"])[0]
            typer.echo(
                f"error: cannot reach the database ({reason}). Set REDLINE_DATABASE_URL, or "
                f"run this while `redline up` runs, from the folder holding its data folder "
                f"(.redline), or with {DATA_VARIABLE}=its data folder.",
                err=True,
            )
            raise typer.Exit(1) from None

    return run


@needs_database
def migrate_cmd() -> None:
    """Upgrade the database (REDLINE_DATABASE_URL) to the newest schema."""
    from redline.server.db import migrate

    settings = _settings()
    migrate(settings.database_url, settings.migrations_dir)
    typer.echo("database is up to date")


def server_cmd(
    host: Annotated[str, typer.Option(help="interface to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port")] = 8080,
    workers: Annotated[
        int,
        typer.Option(
            min=1,
            help="API processes on the one port (each with its own database pool: "
            "docs/operations.md); metrics are summed over them",
        ),
    ] = 1,
) -> None:
    """Migrate the database, then serve the API and the UI."""
    import uvicorn
    from redline.server.core.logs import configure
    from redline.server.db import migrate

    settings = _settings()
    configure(settings.log_json)
    migrate(settings.database_url, settings.migrations_dir)
    # an agent's long poll holds a request up to 20 s: on shutdown it is cut after a moment
    # (the agent retries), instead of keeping the server waiting
    if workers == 1:
        from redline.server.app import create_app

        app: Any = create_app(settings)
        counted: contextlib.AbstractContextManager[None] = contextlib.nullcontext()
    else:  # each process builds its own app from the environment, as this one read it
        app, counted = "redline.server.app:app_from_environment", _metrics_folder()
    with counted:
        uvicorn.run(
            app,
            factory=workers > 1,
            workers=workers,
            host=host,
            port=port,
            log_config=None,
            timeout_graceful_shutdown=SHUTDOWN_GRACE_S,
        )


@contextlib.contextmanager
def _metrics_folder() -> Iterator[None]:
    """``PROMETHEUS_MULTIPROC_DIR`` for the API processes: the operator's (emptied first: files
    of processes gone would count twice), else a temporary one removed at the end."""
    import os
    import shutil
    import tempfile
    from pathlib import Path

    given = os.environ.get("PROMETHEUS_MULTIPROC_DIR")
    folder = Path(given) if given else Path(tempfile.mkdtemp(prefix="redline-metrics-"))
    folder.mkdir(parents=True, exist_ok=True)
    for stale in folder.glob("*.db"):
        stale.unlink()
    os.environ["PROMETHEUS_MULTIPROC_DIR"] = str(folder)
    try:
        yield
    finally:
        if not given:
            shutil.rmtree(folder, ignore_errors=True)


def worker_cmd(
    concurrency: Annotated[int, typer.Option(help="worker processes (or threads)")] = 1,
    loglevel: Annotated[str, typer.Option(help="Celery log level")] = "INFO",
    beat: Annotated[
        bool,
        typer.Option(help="also run the periodic tasks (retention, digests): in one worker only"),
    ] = True,
    queues: Annotated[
        str,
        typer.Option(
            help="the kinds of work this worker takes, comma-separated: ingest, detect, render, "
            "alerts (deliveries: give them a worker of their own so a slow receiver never waits "
            "in front of analysis); analysis = ingest,detect,render; all = every kind"
        ),
    ] = "all",
) -> None:
    """Run a Celery worker that ingests recordings, detects changes and sends alerts."""
    from redline.server.core.tasks import QUEUE_KINDS, queue_of
    from redline.worker.app import celery_app

    settings = celery_app.conf.redline_settings
    named = {"all": list(QUEUE_KINDS), "analysis": ["ingest", "detect", "render"]}
    kinds = [k for word in queues.split(",") for k in named.get(word.strip(), [word.strip()])]
    unknown = [kind for kind in kinds if kind not in QUEUE_KINDS]
    if unknown or not kinds:
        raise typer.BadParameter(
            f"{', '.join(unknown) or queues!r}: choose from all, analysis, "
            + ", ".join(QUEUE_KINDS),
            param_hint="--queues",
        )
    schedule = settings.storage_dir / "celerybeat-schedule"
    schedule.parent.mkdir(parents=True, exist_ok=True)  # beat keeps its state beside the data
    celery_app.worker_main(
        [
            "worker",
            f"--concurrency={concurrency}",
            f"--loglevel={loglevel}",
            f"--queues={','.join(dict.fromkeys(queue_of(settings, k) for k in kinds))}",
            # deliveries wait on the network: threads, not processes
            *(["--pool=threads"] if set(kinds) == {"alerts"} else []),
            *(["--beat", f"--schedule={schedule}"] if beat else []),
        ]
    )


@needs_database
def retention_run(
    days: Annotated[
        int | None, typer.Option(help="age in days (default REDLINE_RETENTION_DAYS)")
    ] = None,
) -> None:
    """Delete raw recordings (MCAP, Parquet) older than the retention age, once; summaries stay."""
    from redline.worker.retention import prune_recordings

    settings = _settings()
    age = settings.retention_days if days is None else days
    count = prune_recordings(settings.database_url, age)
    typer.echo(f"pruned the raw recordings of {count} executions older than {age} days")


@token_app.command("create")
@needs_database
def token_create(
    name: Annotated[str, typer.Argument(help="who or what the token is for")],
    scopes: Annotated[str, typer.Option(help="comma-separated: ci, triage, agent, read, admin")],
    host: Annotated[
        str | None, typer.Option(help="for an agent token: the one host it may act as")
    ] = None,
    labels: Annotated[
        str,
        typer.Option(
            help="for an agent token, comma-separated: the labels its host may register with "
            "(none: it runs only the jobs of components that ask for no label)"
        ),
    ] = "",
    components: Annotated[
        str,
        typer.Option(
            help="for a ci, triage or agent token, comma-separated: the only components it "
            "acts on (none: every one)"
        ),
    ] = "",
) -> None:
    """Create a token and print it; it is stored only as a hash and cannot be shown again."""
    from redline.server.db import session_factory
    from redline.server.services.errors import BadRequest, ServiceError
    from redline.server.services.tokens import issue_token

    with session_factory(_settings().database_url)() as session:
        try:
            _, secret = issue_token(session, name, scopes, host, labels, components)
        except ServiceError as exc:  # bad input (an unknown scope...), or a live token so named
            typer.echo(exc.detail, err=True)
            # 2, as for any bad option: what was asked is wrong, not the state it met
            raise typer.Exit(2 if isinstance(exc, BadRequest) else 1) from None
    typer.echo(secret)


@token_app.command("list")
@needs_database
def token_list() -> None:
    """List tokens: id, name, scopes, host, labels, components, created, last used, revoked."""
    from redline.server.db import session_factory
    from redline.server.services.tokens import list_tokens

    with session_factory(_settings().database_url)() as session:
        typer.echo("id\tname\tscopes\thost\tlabels\tcomponents\tcreated\tlast used\tstate")
        for token in list_tokens(session):
            used = token.last_used.isoformat(timespec="seconds") if token.last_used else "never"
            state = "revoked" if token.revoked else "live"
            typer.echo(
                f"{token.id}\t{token.name}\t{','.join(token.scopes)}\t"
                f"{token.host or '-'}\t{','.join(token.labels or []) or '-'}\t"
                f"{','.join(token.components or []) or 'all'}\t"
                f"{token.created:%Y-%m-%d}\t{used}\t{state}"
            )


@token_app.command("revoke")
@needs_database
def token_revoke(
    name_or_id: Annotated[str, typer.Argument(help="the token's id, or its name")],
) -> None:
    """Revoke a token at once; requests carrying it are refused from now on."""
    from redline.server.db import session_factory
    from redline.server.services.errors import NotFound
    from redline.server.services.tokens import revoke_token

    with session_factory(_settings().database_url)() as session:
        try:
            revoked = revoke_token(session, name_or_id)
        except NotFound as exc:
            typer.echo(exc.detail, err=True)
            raise typer.Exit(1) from None
        for token in revoked:
            typer.echo(f"revoked {token.id} {token.name}")


@user_app.command("create")
@needs_database
def user_create(
    name: Annotated[str, typer.Argument(help="the name they sign in with")],
    scopes: Annotated[
        str,
        typer.Option(
            help="comma-separated: read (look), triage (look and triage), ci (report "
            "revisions), admin (all)"
        ),
    ],
    password_stdin: Annotated[
        bool, typer.Option("--password-stdin", help="read the password from standard input")
    ] = False,
) -> None:
    """Create a user who signs in with a password (asked for, or read from standard input;
    never an argument, which every user of the machine can see in the process list)."""
    import getpass
    import sys

    from redline.server.db import session_factory
    from redline.server.services.errors import ServiceError
    from redline.server.services.signin import create_user

    if password_stdin:
        password = sys.stdin.readline().rstrip("\n")
    else:
        password = getpass.getpass("password: ")
        if getpass.getpass("again: ") != password:
            typer.echo("the two passwords differ", err=True)
            raise typer.Exit(1)
    with session_factory(_settings().database_url)() as session:
        try:
            user = create_user(session, name, password, scopes)
        except ServiceError as exc:  # a short password, an unknown scope, a taken name
            typer.echo(exc.detail, err=True)
            raise typer.Exit(1) from None
    typer.echo(f"created user {user.name} ({','.join(user.scopes)})")


@user_app.command("list")
@needs_database
def user_list() -> None:
    """List users: name, scopes, created, state (live or disabled)."""
    from redline.server.db import session_factory
    from redline.server.services.signin import list_users

    with session_factory(_settings().database_url)() as session:
        typer.echo("name\tscopes\tcreated\tstate")
        for user in list_users(session):
            state = "disabled" if user.disabled else "live"
            typer.echo(f"{user.name}\t{','.join(user.scopes)}\t{user.created:%Y-%m-%d}\t{state}")


@needs_database
def _user_disabled(name: str, disabled: bool) -> None:
    from redline.server.db import session_factory
    from redline.server.services.errors import NotFound
    from redline.server.services.signin import set_disabled

    with session_factory(_settings().database_url)() as session:
        try:
            user = set_disabled(session, name, disabled)
        except NotFound as exc:
            typer.echo(exc.detail, err=True)
            raise typer.Exit(1) from None
    typer.echo(f"{'disabled' if disabled else 'enabled'} user {user.name}")


@user_app.command("disable")
def user_disable(name: Annotated[str, typer.Argument(help="the user's name")]) -> None:
    """Disable a user: they cannot sign in, and their open sessions end at once."""
    _user_disabled(name, True)


@user_app.command("enable")
def user_enable(name: Annotated[str, typer.Argument(help="the user's name")]) -> None:
    """Let a disabled user sign in again."""
    _user_disabled(name, False)


retention_app.command("run")(retention_run)


def register(app: typer.Typer) -> None:
    app.command("server")(server_cmd)
    app.command("worker")(worker_cmd)
    app.command("migrate")(migrate_cmd)
    app.add_typer(token_app, name="token")
    app.add_typer(user_app, name="user")
    app.add_typer(retention_app, name="retention")
