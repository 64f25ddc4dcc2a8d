"""Resource-usage models: what to train on, a model as the API shows it, run-time alerts."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, Field
from redline.server.schemas.common import RequestBody
from redline.server.schemas.fields import StoredId, Title, one_line


class ModelRequest(RequestBody):
    """What to train on: executions chosen by revision titles and/or ids (none named: the newest
    revision's), optionally only one test case's segments, and the process to model."""

    revisions: list[Title] = Field(default_factory=list, max_length=1000)
    executions: list[StoredId] = Field(default_factory=list, max_length=10_000)
    case: str | None = Field(default=None, max_length=200, description="one test case only")
    process: str | None = Field(
        default=None, max_length=200, description="the component process (default: the only one)"
    )
    received_only: bool = Field(
        default=False,
        description="features of what the component receives only: for watching, where a model "
        "that also sees what it sends explains a stall's lower CPU by its lower output",
    )


class ModelOut(BaseModel):
    id: int
    component: str
    state: str = Field(description="queued, running, done or failed")
    error: str
    request: dict[str, Any]
    process: str
    metrics: dict[str, Any] = Field(
        description="per target: cv_rmse, cv_baseline_rmse, cv_ratio, threshold, grid point"
    )
    provenance: dict[str, Any]
    created: datetime
    finished: datetime | None
    file: str | None = Field(description="where to download the model file for `redline watch`")


#: one line (an audit's "cpu\r\nx" made every mail of the alert fail; a U+202E reversed it)
_AlertText = AfterValidator(one_line)


class RuntimeAlertIn(RequestBody):
    target: Annotated[str, _AlertText] = Field(min_length=1, max_length=50)
    started: bool = Field(description="a fault began (true) or ended (false)")
    residual: float = Field(allow_inf_nan=False)
    threshold: float = Field(allow_inf_nan=False)
    step: int = Field(default=0, ge=0, le=2**31 - 1)  # stored in 32 bits: refused by name
    model: StoredId | None = Field(default=None, description="the server's model id, if from there")
    host: str = Field(
        default="", max_length=200, description="the reporting token's host (the default); no other"
    )
    process: Annotated[str, _AlertText] = Field(default="", max_length=200)


class RuntimeAlertOut(RuntimeAlertIn):
    target: str  # as stored (an older Redline took any text): shown, not judged again
    process: str
    id: int
    at: datetime
