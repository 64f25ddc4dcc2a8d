"""Push webhooks: the parts of GitHub's and GitLab's push events Redline reads, and its answer."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class PushCommit(BaseModel):
    model_config = ConfigDict(extra="ignore")
    id: str = Field(min_length=1, max_length=200)
    message: str = ""
    timestamp: str | None = None  # checked per commit: one bad commit does not lose the push


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
    # not `homepage`: any repository admin sets it to whatever they like

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


class RefusedCommit(BaseModel):
    commit: str
    reason: str


class WebhookResult(BaseModel):
    detail: str
    created: list[PushRevision] = Field(
        default_factory=list, description="revisions new with this delivery"
    )
    existing: int = Field(default=0, description="commits already known (a repeated delivery)")
    refused: list[RefusedCommit] = Field(
        default_factory=list, description="commits not recorded, and why"
    )
