"""Settings from the environment (prefix ``REDLINE_``), e.g. ``REDLINE_DATABASE_URL``."""

from __future__ import annotations

from functools import lru_cache
from importlib.resources import files
from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict
from redline.recording.mcap_bytes import MAX_UNPACKED_BYTES

#: the installed package: the UI's templates and static files, and the migrations, ship in it
PACKAGE = Path(str(files("redline.server")))


class Settings(BaseSettings):
    """Everything the server and the worker need to know; each field is ``REDLINE_<NAME>``."""

    model_config = SettingsConfigDict(env_prefix="REDLINE_", extra="ignore")

    database_url: str = "postgresql+psycopg://postgres@127.0.0.1:5432/redline"
    redis_url: str = "redis://127.0.0.1:6379/0"
    queue: str = "redline"  # the Celery queue; distinct names keep stacks sharing a Redis apart
    storage_dir: Path = Path("redline-data/storage")
    web_dir: Path = PACKAGE / "ui"  # templates/ and static/
    migrations_dir: Path = PACKAGE / "migrations"
    lease_seconds: int = 120
    max_attempts: int = 3
    max_upload_bytes: int = 2 * 1024**3  # one MCAP recording
    # what an upload's chunks may unpack to in all: a small file must not unpack to gigabytes
    max_unpacked_bytes: int = MAX_UNPACKED_BYTES
    max_webhook_bytes: int = 25 * 1024**2  # GitHub's own cap on a delivery
    max_import_bytes: int = 32 * 1024**2  # an LNT report or a results import
    max_json_bytes: int = 1024**2  # any other request body
    # may a component's repository be a local path or file:// URL? (`redline up` allows it)
    allow_file_repos: bool = False
    webhook_secret: str = ""  # GitHub/GitLab push secret; a component's own one overrides it
    # token: reading needs a `read` (or `triage`) token
    read_access: Literal["open", "token"] = "open"
    retention_days: int = 90  # raw recordings (MCAP, Parquet) older than this are deleted
    log_json: bool = False  # log JSON lines instead of text
    # the address people open Redline's pages at: links in mails, webhooks and commit statuses
    public_url: str = "http://127.0.0.1:8000"
    # alerts by mail (docs/alerts.md); no host: mail subscriptions fail, saying so
    smtp_host: str = ""
    smtp_port: int = 25
    smtp_user: str = ""
    smtp_password: SecretStr = SecretStr("")
    smtp_tls: Literal["none", "starttls", "tls"] = "starttls"
    smtp_from: str = "redline@localhost"
    smtp_ca_file: Path | None = None  # a private CA the SMTP server's certificate comes from
    # outgoing webhooks, mails and commit statuses: one try's timeout, tries, first retry's wait
    alert_timeout_s: float = 10.0
    alert_max_attempts: int = 10
    alert_retry_s: float = 30.0
    # database connections of one process (an API process or a worker): a pool this big, and
    # this many more in a burst; each API process of `redline server --workers N` has its own
    # (docs/operations.md sizes them against Postgres's max_connections)
    db_pool_size: int = 5
    db_max_overflow: int = 5
    db_pool_timeout_s: float = 10.0
    # behind PgBouncer in transaction mode: no pool of our own, no prepared statements
    db_pgbouncer: bool = False
    # a task taken by a worker that died (SIGKILL, a lost host) goes back to the queue this long
    # after it was taken (Redis's visibility timeout); longer than the longest task runs, or a
    # second worker starts it again while the first still runs it (harmless: tasks are
    # idempotent, but the work is done twice)
    task_visibility_s: float = 3600.0
    # confirmation pairs the host was busy in are queued once more, and not run before this
    # long has passed, when the work that loaded the host may have ended (docs/detection.md)
    quiet_wait_s: float = Field(default=300.0, ge=0, le=7 * 24 * 3600)
    # a re-analysis is judged in this many parts, split by series, each a task any detect
    # worker takes (docs/operations.md): as many as the worker processes that should share it
    reanalysis_parts: int = Field(default=2, ge=1, le=64)


@lru_cache
def get_settings() -> Settings:
    """The settings of this process, read once from the environment."""
    return Settings()
