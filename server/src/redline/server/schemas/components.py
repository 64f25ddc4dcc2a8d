"""Components: what is measured, and the settings an admin gives it."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field, field_validator
from redline.server.schemas.common import RequestBody
from redline.server.schemas.fields import (
    Branch,
    ComponentName,
    Description,
    SuitePath,
    WebhookSecret,
    Word,
)

#: a repository's URL or path, at most: it is indexed (Postgres indexes 2,704 bytes a row), and
#: a probe's 3,000 letters were answered "the database is unavailable"
REPO_LENGTH = 1_000


class ComponentSettings(RequestBody):
    """What PATCH may change; every field is optional there."""

    repo: str | None = Field(
        default=None, max_length=REPO_LENGTH, description="URL or path; https/ssh/.git all match"
    )
    branch: Branch | None = Field(
        default=None,
        description="the default branch; pushes to it become revisions",
    )
    suite: SuitePath | None = Field(
        default=None, description="path of the suite file inside the repository"
    )
    executions: int | None = Field(
        default=None, ge=1, le=100, description="executions (jobs) per revision"
    )
    host_labels: list[Word] | None = Field(
        default=None, description="labels a host needs to run its jobs"
    )
    webhook_secret: WebhookSecret | None = Field(
        default=None, description="overrides REDLINE_WEBHOOK_SECRET for this repository; '' clears"
    )
    description: Description | None = None

    @field_validator("repo", "branch", "suite")
    @classmethod
    def _kept_or_changed(cls, value: str | None) -> str | None:
        """Never emptied: a trial's ``"repo": ""`` was saved, and every revision reported
        after it failed on its host ("no repository is configured"); the settings page keeps a
        field left blank."""
        if value == "":
            raise ValueError(
                "cannot be emptied: the component's jobs need it (leave it out, or null, to "
                "keep it)"
            )
        return value


class ComponentCreate(RequestBody):
    name: ComponentName
    repo: str = Field(
        default="",
        max_length=REPO_LENGTH,
        description="https://, ssh:// or git:// URL, or user@host:path; "
        "a local path or file:// only where REDLINE_ALLOW_FILE_REPOS is set",
    )
    branch: Branch = Field(
        default="main",
        description="the default branch; pushes to it become revisions",
    )
    suite: SuitePath = Field(default="", description="path of the suite file inside the repository")
    executions: int = Field(default=1, ge=1, le=100, description="executions per revision")
    host_labels: list[Word] = Field(
        default_factory=list, description="labels a host needs to run its jobs"
    )
    webhook_secret: WebhookSecret | None = Field(
        default=None, description="overrides REDLINE_WEBHOOK_SECRET"
    )
    description: Description = ""

    @field_validator("branch")
    @classmethod
    def _a_branch(cls, value: str) -> str:
        if not value:
            raise ValueError("must name the default branch (leave it out for 'main')")
        return value


class ComponentOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    name: str
    repo: str
    branch: str
    suite: str
    executions: int
    host_labels: list[str] = Field(default_factory=list)
    description: str = ""
    has_webhook_secret: bool = Field(default=False, description="the secret is never shown")
    created: datetime
