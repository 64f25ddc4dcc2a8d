"""Revisions as CI reports them, and as the API shows them with their jobs and executions."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, StringConstraints
from redline.server.schemas.common import RequestBody
from redline.server.schemas.fields import Branch, CommitTime, RunCommit, SortKey, Title


class RevisionCreate(RequestBody):
    component: str = Field(min_length=1, max_length=200)
    title: Title
    sort_key: SortKey = Field(description="orders revisions; '9' < '10' (a whole number: its text)")
    commit: RunCommit = Field(description="what the performance hosts check out and build")
    repo: str = Field(
        default="",
        description="optional; when given, it must name the "
        "component's own repository (only an admin changes that, by PATCH)",
    )
    branch: Branch = Field(default="", description="defaults to the component's branch")
    message: str = Field(default="", max_length=10_000, description="the commit message")
    committed_at: CommitTime | None = None
    remotes: list[Annotated[str, StringConstraints(max_length=2000)]] = Field(
        default_factory=list,
        max_length=20,
        description="the reporting work tree's remote URLs, without credentials (`redline ci "
        "report` sends them): when none is the component's repository, the answer's "
        "`warning` says so (a mirror may be meant, so it is not refused)",
    )


class RevisionPatch(RequestBody):
    """What an admin may correct of a revision: its sort key (`services.revision_keys`)."""

    sort_key: SortKey = Field(description="orders revisions; '9' < '10' (a whole number: its text)")


class RevisionCreated(BaseModel):
    revision_id: int
    title: str = Field(description="the revision's title: the first report's, when reported before")
    job_ids: list[int]
    warning: str = Field(
        default="",
        description="what may be wrong with the report: the work tree's `remotes` are not the "
        "component's repository, so the hosts may not find the commit",
    )


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
    pair: int = Field(
        default=0,
        description="a confirmation run's pair (from 1, numbered on when the revision is judged "
        "again against another baseline and pairs are queued anew); 0 for the revision's own",
    )
    confirms: str | None = Field(
        default=None, description="the revision a confirmation run confirms (its title)"
    )
    not_before: datetime | None = Field(
        default=None,
        description="a confirmation pair queued again because the host was busy in the pairs "
        "before it is not run before this time; null for every other job",
    )


class RevisionOut(BaseModel):
    id: int
    title: str
    sort_key: str
    commit: str
    measured_commit: str = Field(
        default="",
        description="the hash of the commit its runs checked out, pinned by the first a host "
        "uploaded (every later run of it checks this hash out, not `commit`'s name, a branch's "
        "perhaps); empty before a host ran it, or for imported results",
    )
    repo: str
    branch: str = ""
    message: str = Field(default="", description="its commit message, as CI reported it")
    subject: str = Field(default="", description="the message's first line")
    committed_at: datetime | None = None
    state: str = Field(description="derived from the revision's jobs and its analysis")
    created: datetime
    analyzed_at: datetime | None = Field(description="when changes were last detected")


class RevisionDetail(RevisionOut):
    component: str
    jobs: list[JobOut]
    verdict: str = Field(
        default="",
        description="what the alarm method found, in a few words, or why there is no verdict "
        "yet (e.g. how many more baseline executions it waits for), or none will come (its jobs "
        "failed, with their reasons, or were cancelled); empty while one may still come",
    )
