"""The agent's job protocol: registering a host, leasing, heartbeats, uploads, failures."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, Field
from redline.server.schemas.common import RequestBody
from redline.server.schemas.fields import HostName, Line, ParamValue, Word


class RegisterRequest(RequestBody):
    # shown in the pages and `redline token list`, where a CR/LF or a space would break a row
    # (a pool token registered "compose-\r\nX")
    name: HostName = Field(min_length=1)
    # shown on the home page: one line each, as a parameter's value
    fingerprint: dict[Line, ParamValue] = Field(default_factory=dict, max_length=100)
    labels: list[Word] = Field(default_factory=list)


class RegisterResponse(BaseModel):
    host_id: int


class HostRequest(RequestBody):
    host: HostName = Field(min_length=1)


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
    cases: list[str] = Field(
        default_factory=list,
        description="run only these test cases of the suite; empty: every case (a "
        "confirmation run names its parameter_sets instead)",
    )
    parameter_sets: dict[str, list[str]] = Field(
        default_factory=dict,
        description="run the suite as far as the last of these parameter sets, per case "
        '(canonical JSON with sorted keys, as series name them: {"legs_and_rate": '
        '[\'{"legs":8,"rate":10}\']}; a confirmation run: those with a suspected change), '
        "everything before it as usual; empty: the whole suite",
    )
    sets_alone: bool = Field(
        default=False,
        description="run only the parameter_sets named, each after its warm-up, not the "
        "suite as far as the last of them (a confirmation run of a change in CPU or latency; "
        "one of memory, threads or files runs what came before too, since it depends on it)",
    )
    busy_matters: bool = Field(
        default=True,
        description="whether a phase the host was busy in spoils the run, so that the agent "
        "runs it again at once (false: a confirmation run of changes in memory, threads or "
        "files only, which are judged in a busy phase too)",
    )


class HeartbeatResponse(BaseModel):
    lease_expires_at: datetime


class UploadResponse(BaseModel):
    execution_id: int
    ingest_queued: bool = Field(description="whether ingestion was handed to the workers")


class FailRequest(RequestBody):
    host: str = Field(min_length=1, max_length=200, description="the host holding the job")
    reason: str = Field(min_length=1, max_length=10_000)
    of_commit: bool = Field(
        default=False,
        description="the commit's own fault (its suite file or build), which every execution "
        "of it meets alike: the revision's other executions still queued are not run",
    )


class JobStateOut(BaseModel):
    id: int
    state: str
    reason: str
