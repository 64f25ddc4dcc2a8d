"""What is measured and who measures it: components, their revisions, the jobs that run them on
performance hosts, and each job's execution (its recording)."""

from __future__ import annotations

import enum
from datetime import datetime
from typing import Any

from redline.server.models.base import Base, utcnow
from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    Enum,
    ForeignKey,
    Integer,
    String,
    Text,
    Tuple,
    UniqueConstraint,
    tuple_,
)
from sqlalchemy.orm import Mapped, mapped_column, relationship


class JobState(enum.StrEnum):
    queued = "queued"
    leased = "leased"
    running = "running"
    uploaded = "uploaded"
    done = "done"
    failed = "failed"
    cancelled = "cancelled"


#: a job in these states is held by a host
HELD = (JobState.leased, JobState.running)
#: jobs that have not ended: their revision's verdict may still change
UNENDED = (JobState.queued, *HELD, JobState.uploaded)
#: a job in these states gave no results: it failed (its ingestion too) or was cancelled
DID_NOT_RUN = (JobState.failed, JobState.cancelled)
#: a job in these states runs no more
FINISHED = (JobState.done, *DID_NOT_RUN)


class Component(Base):
    __tablename__ = "component"
    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    repo: Mapped[str] = mapped_column(Text, default="")
    branch: Mapped[str] = mapped_column(String(200), default="main")
    suite: Mapped[str] = mapped_column(Text, default="")
    executions: Mapped[int] = mapped_column(Integer, default=1)
    created: Mapped[datetime] = mapped_column(default=utcnow)
    # redline.server.services.repos.repo_key(repo): https/ssh/.git spellings of one repository
    repo_key: Mapped[str] = mapped_column(Text, default="", index=True)
    host_labels: Mapped[list[str]] = mapped_column(JSON, default=list)  # a host must have all
    webhook_secret: Mapped[str | None] = mapped_column(Text, default=None)  # else the setting
    description: Mapped[str] = mapped_column(Text, default="")
    #: where its revisions' verdicts go as commit statuses: provider (github, gitlab), api_url,
    #: repository (owner/name or a GitLab project id or path), token; empty: nowhere
    commit_status: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    #: when a host last leased one of its revisions' jobs: leases go to the component served
    #: longest ago first (`redline.server.services.jobs.lease_job`)
    last_leased_at: Mapped[datetime | None] = mapped_column(default=None)


class Revision(Base):
    __tablename__ = "revision"
    __table_args__ = (UniqueConstraint("component_id", "title"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    component_id: Mapped[int] = mapped_column(ForeignKey("component.id"), index=True)
    title: Mapped[str] = mapped_column(String(200))
    sort_key: Mapped[str] = mapped_column(String(200))
    # sort_key with digit runs made comparable as text ("9" < "10"); "C" collation: bytewise order
    order_key: Mapped[str] = mapped_column(String(1000, collation="C"), index=True)
    commit: Mapped[str] = mapped_column(String(200), default="")
    #: the hash of the commit the first run a host uploaded checked out: every later run of the
    #: revision (its own, confirmation pairs) checks that hash out, not ``commit``'s name, which
    #: may be a branch's that has moved since ("" until then; never set by an import)
    measured_commit: Mapped[str] = mapped_column(String(64), default="", server_default="")
    repo: Mapped[str] = mapped_column(Text, default="")
    branch: Mapped[str] = mapped_column(String(200), default="")
    message: Mapped[str] = mapped_column(Text, default="")
    committed_at: Mapped[datetime | None] = mapped_column(default=None)
    created: Mapped[datetime] = mapped_column(default=utcnow)
    # set by detection, cleared by ingestion: the changes shown are those of all ingested data
    analyzed_at: Mapped[datetime | None] = mapped_column(default=None)
    #: counted up whenever analyzed_at is cleared: detection marks the revision analysed only if
    #: it is what it read before judging (`redline.server.services.analysed`)
    inputs: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    component: Mapped[Component] = relationship()
    jobs: Mapped[list[Job]] = relationship(
        back_populates="revision", order_by="Job.execution_index", foreign_keys="Job.revision_id"
    )

    @property
    def subject(self) -> str:
        """The first line of its commit message, as CI reported it ("" without one): what a
        reader of a page or an alert knows a commit by (a trial looked its slow commit up in
        git: no page, alert or answer said what it was)."""
        return next((line.strip() for line in self.message.splitlines() if line.strip()), "")[:200]

    @property
    def place(self) -> tuple[str, int]:
        """Where the revision stands in its component's history (`revision_place`)."""
        return (self.order_key, self.id)


def revision_place() -> Tuple:
    """A revision's place in its component's history, in SQL: its sort key, then the order it was
    reported in, so revisions of one key (commits of one second) keep that order everywhere;
    compare it with `Revision.place`, never with the sort key alone."""
    return tuple_(Revision.order_key, Revision.id)


class Job(Base):
    __tablename__ = "job"
    __table_args__ = (UniqueConstraint("revision_id", "execution_index"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    revision_id: Mapped[int] = mapped_column(ForeignKey("revision.id"), index=True)
    execution_index: Mapped[int] = mapped_column(Integer)
    state: Mapped[JobState] = mapped_column(
        Enum(JobState, name="job_state", native_enum=False, length=20),
        default=JobState.queued,
        index=True,
    )
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    lease_expires_at: Mapped[datetime | None] = mapped_column(default=None)
    host_id: Mapped[int | None] = mapped_column(ForeignKey("host.id"), default=None)
    reason: Mapped[str] = mapped_column(Text, default="")
    labels: Mapped[list[str]] = mapped_column(JSON, default=list)  # the host pool: all required
    #: a confirmation run (`redline.worker.confirm_runs`): its pair (from 1, numbered on for the
    #: pairs queued anew against another baseline; 0 for a revision's own executions), the
    #: flagged revision it confirms, and the host it must run on
    pair: Mapped[int] = mapped_column(Integer, default=0)
    confirms_revision_id: Mapped[int | None] = mapped_column(
        ForeignKey("revision.id"), default=None, index=True
    )
    pinned_host_id: Mapped[int | None] = mapped_column(ForeignKey("host.id"), default=None)
    #: a fresh run of one of the revision's own executions the host was busy in
    #: (`redline.worker.remeasure`): that execution's job; it counts as one of the revision's own
    remeasures_job_id: Mapped[int | None] = mapped_column(
        ForeignKey("job.id", ondelete="SET NULL"), default=None
    )
    #: not leased before this time: a confirmation pair queued again because the host was busy
    #: in the pairs before it (`redline.worker.quiet_pairs`); None for every other job
    not_before: Mapped[datetime | None] = mapped_column(default=None)
    #: the test cases to run; []: all (no job the server makes names any since 2026-11-27: a
    #: confirmation run names its `parameter_sets` instead)
    cases: Mapped[list[str]] = mapped_column(JSON, default=list)
    #: run the suite as far as the last of these parameter sets (canonical, as `Series.params`),
    #: per case; {}: all of it (a confirmation run's: the sets with a suspected change)
    parameter_sets: Mapped[dict[str, list[str]]] = mapped_column(JSON, default=dict)
    #: run those parameter sets only, not as far as the last of them (a confirmation run of
    #: changes in what a component does per unit of work, none in what it has accumulated:
    #: `redline.detect.counters.is_cumulative`)
    sets_alone: Mapped[bool] = mapped_column(Boolean, default=False)
    #: whether a phase the host was busy in spoils the run, so the agent runs it again at once
    #: (false: a confirmation run of changes in what a component holds only, judged anyway:
    #: `redline.detect.counters.is_held`)
    busy_matters: Mapped[bool] = mapped_column(Boolean, default=True)
    created: Mapped[datetime] = mapped_column(default=utcnow)
    updated: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)
    revision: Mapped[Revision] = relationship(back_populates="jobs", foreign_keys=[revision_id])
    host: Mapped[Host | None] = relationship(foreign_keys=[host_id])
    confirms_revision: Mapped[Revision | None] = relationship(foreign_keys=[confirms_revision_id])
    execution: Mapped[Execution | None] = relationship(back_populates="job")


class Execution(Base):
    __tablename__ = "execution"
    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[int] = mapped_column(ForeignKey("job.id"), unique=True)
    revision_id: Mapped[int] = mapped_column(ForeignKey("revision.id"), index=True)
    recording_path: Mapped[str] = mapped_column(Text)
    sha256: Mapped[str] = mapped_column(String(64), unique=True)
    size: Mapped[int] = mapped_column(BigInteger, default=0)
    meta: Mapped[dict[str, Any]] = mapped_column("metadata", JSON, default=dict)
    created: Mapped[datetime] = mapped_column(default=utcnow)
    pruned_at: Mapped[datetime | None] = mapped_column(default=None)  # raw files deleted
    job: Mapped[Job] = relationship(back_populates="execution")


class Host(Base):
    __tablename__ = "host"
    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    fingerprint: Mapped[dict[str, Any]] = mapped_column(default=dict)
    labels: Mapped[list[str]] = mapped_column(JSON, default=list)
    last_seen: Mapped[datetime] = mapped_column(default=utcnow)
