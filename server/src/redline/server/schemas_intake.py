"""Request and response bodies of intake: webhooks, tokens and result imports."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field


class PushCommit(BaseModel):
    model_config = ConfigDict(extra="ignore")
    id: str = Field(min_length=1, max_length=200)
    message: str = ""
    timestamp: datetime | None = None


class PushRepository(BaseModel):
    """The URL fields GitHub (repository) and GitLab (project, repository) send."""

    model_config = ConfigDict(extra="ignore")
    clone_url: str | None = None
    ssh_url: str | None = None
    html_url: str | None = None
    git_url: str | None = None
    url: str | None = None
    git_http_url: str | None = None
    git_ssh_url: str | None = None
    web_url: str | None = None
    homepage: str | None = None

    def urls(self) -> list[str]:
        return [url for url in self.model_dump().values() if isinstance(url, str) and url]


class PushEvent(BaseModel):
    """The parts of a GitHub or GitLab push event that Redline reads."""

    model_config = ConfigDict(extra="ignore")
    ref: str = ""
    repository: PushRepository | None = None
    project: PushRepository | None = None
    commits: list[PushCommit] = Field(default_factory=list)
    head_commit: PushCommit | None = None


class PushRevision(BaseModel):
    component: str
    revision_id: int
    title: str
    sort_key: str
    job_ids: list[int]


class WebhookResult(BaseModel):
    detail: str
    created: list[PushRevision] = Field(
        default_factory=list, description="revisions new with this delivery"
    )
    existing: int = Field(default=0, description="commits already known (a repeated delivery)")


class TokenCreate(BaseModel):
    name: str = Field(min_length=1, max_length=200)
    scopes: list[str] = Field(min_length=1, description="ci, agent, read, admin")
    host: str | None = Field(
        default=None, max_length=200, description="for an agent token: the one host it may act as"
    )


class TokenOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    name: str
    scopes: list[str]
    host: str | None
    created: datetime
    last_used: datetime | None
    revoked: bool


class TokenCreated(TokenOut):
    token: str = Field(description="the secret; shown once, stored only as a hash")


class ImportResult(BaseModel):
    component: str
    revision: str
    revision_id: int
    execution_id: int
    series: int = Field(description="series with a summary in this import")
    created: bool = Field(description="false when the same report was imported before")


class ResultValue(BaseModel):
    """One measured series of a generic result: its name and its samples."""

    case: str = Field(min_length=1, max_length=200)
    phase: str = Field(default="main", min_length=1, max_length=200)
    params: dict[str, Any] = Field(default_factory=dict)
    process: str = Field(default="benchmark", min_length=1, max_length=200)
    counter: str = Field(min_length=1, max_length=200)
    values: list[Annotated[float, Field(allow_inf_nan=False)]] = Field(
        min_length=1, description="finite samples (NaN and infinities are refused)"
    )


class ResultsImport(BaseModel):
    """A benchmark's results without the SDK; see docs/api.md."""

    component: str = Field(min_length=1, max_length=200)
    revision: str = Field(min_length=1, max_length=200, description="the revision's title")
    sort_key: str = Field(min_length=1, max_length=200)
    commit: str = Field(default="", max_length=200)
    host: str = Field(default="", max_length=200, description="where it was measured")
    results: list[ResultValue] = Field(min_length=1)
