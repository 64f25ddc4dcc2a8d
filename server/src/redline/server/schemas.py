"""Request and response bodies of the HTTP API (they make the OpenAPI document complete)."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field


class ComponentSettings(BaseModel):
    """What PATCH may change; every field is optional there."""

    repo: str | None = Field(default=None, description="URL or path; https/ssh/.git all match")
    branch: str | None = Field(
        default=None,
        max_length=200,
        description="the default branch; pushes to it become revisions",
    )
    suite: str | None = Field(
        default=None, description="path of the suite file inside the repository"
    )
    executions: int | None = Field(
        default=None, ge=1, le=100, description="executions (jobs) per revision"
    )
    host_labels: list[str] | None = Field(
        default=None, description="labels a host needs to run its jobs"
    )
    webhook_secret: str | None = Field(
        default=None, description="overrides REDLINE_WEBHOOK_SECRET for this repository; '' clears"
    )
    description: str | None = None


class ComponentCreate(BaseModel):
    name: str = Field(min_length=1, max_length=200, pattern=r"^[A-Za-z0-9._-]+$")
    repo: str = Field(default="", description="URL or path; https/ssh/.git spellings all match")
    branch: str = Field(
        default="main",
        max_length=200,
        description="the default branch; pushes to it become revisions",
    )
    suite: str = Field(default="", description="path of the suite file inside the repository")
    executions: int = Field(default=1, ge=1, le=100, description="executions per revision")
    host_labels: list[str] = Field(
        default_factory=list, description="labels a host needs to run its jobs"
    )
    webhook_secret: str | None = Field(default=None, description="overrides REDLINE_WEBHOOK_SECRET")
    description: str = ""


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


class RevisionCreate(BaseModel):
    component: str = Field(min_length=1, max_length=200)
    title: str = Field(min_length=1, max_length=200)
    sort_key: str = Field(min_length=1, max_length=200, description="orders revisions; '9' < '10'")
    commit: str = Field(default="", max_length=200)
    repo: str = Field(default="", description="defaults to the component's repository")
    branch: str = Field(
        default="", max_length=200, description="defaults to the component's branch"
    )
    message: str = Field(default="", max_length=10_000, description="the commit message")
    committed_at: datetime | None = None


class RevisionCreated(BaseModel):
    revision_id: int
    job_ids: list[int]


class ExecutionOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    sha256: str
    size: int
    created: datetime


class JobOut(BaseModel):
    id: int
    execution_index: int
    state: str
    attempts: int
    reason: str
    host: str | None
    lease_expires_at: datetime | None
    execution: ExecutionOut | None


class RevisionOut(BaseModel):
    id: int
    title: str
    sort_key: str
    commit: str
    repo: str
    branch: str = ""
    committed_at: datetime | None = None
    state: str = Field(description="derived from the revision's jobs and its analysis")
    created: datetime
    analyzed_at: datetime | None = Field(description="when changes were last detected")


class RevisionDetail(RevisionOut):
    component: str
    jobs: list[JobOut]


class SeriesPoint(BaseModel):
    revision: str
    sort_key: str
    n: int
    mean: float
    std: float


class SeriesRef(BaseModel):
    """A series' identity: component-wide unique by case, phase, params, process and counter."""

    id: int
    label: str
    case: str
    phase: str
    params: dict[str, Any]
    process: str
    counter: str


class SeriesOut(SeriesRef):
    points: list[SeriesPoint]


class ChangeOut(BaseModel):
    series: SeriesRef
    revision: str
    baseline: str
    method: str
    score: float
    p_value: float
    effect: float | None = Field(description="relative change of the mean; null when undefined")
    flagged: bool
    created: datetime


class RegisterRequest(BaseModel):
    name: str = Field(min_length=1, max_length=200)
    fingerprint: dict[str, Any] = Field(default_factory=dict)
    labels: list[str] = Field(default_factory=list)


class RegisterResponse(BaseModel):
    host_id: int


class HostRequest(BaseModel):
    host: str = Field(min_length=1, max_length=200)


class LeasedRevision(BaseModel):
    title: str
    sort_key: str


class LeasedJob(BaseModel):
    id: int
    component: str
    repo: str
    commit: str
    suite: str
    revision: LeasedRevision
    execution_index: int
    lease_expires_at: datetime


class HeartbeatResponse(BaseModel):
    lease_expires_at: datetime


class UploadResponse(BaseModel):
    execution_id: int
    ingest_queued: bool = Field(description="whether ingestion was handed to the workers")


class FailRequest(BaseModel):
    host: str = Field(min_length=1, max_length=200, description="the host holding the job")
    reason: str = Field(min_length=1, max_length=10_000)


class JobStateOut(BaseModel):
    id: int
    state: str
    reason: str


class Problem(BaseModel):
    detail: str
