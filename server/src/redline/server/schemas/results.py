"""What was measured, as the read API shows it: series and their points, executions, changes,
comparisons of two revisions."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, Field


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
    kind: Literal["counter", "driver", "host", "redline", "recorder"] = Field(
        description="counter: a component process's, from the monitor; driver: measured by the "
        "test driver; host: the machine's context; redline: Redline's own processes' CPU; "
        "recorder: the recorder's own counts"
    )
    worse: Literal["increase", "decrease"] = Field(
        description="the direction of a change for the worse (a lower achieved rate is worse)"
    )
    judged: bool = Field(
        description="whether a verdict is asked of it by default (not the "
        "host's, not the CPU's user/system split, not a driver's load)"
    )


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


class SummaryOut(BaseModel):
    """One execution's statistics of one series."""

    revision: str
    sort_key: str
    execution_id: int
    n: int
    mean: float
    std: float
    min: float
    p5: float
    p25: float
    p50: float
    p75: float
    p95: float
    max: float
    sketch: list[float] | None = Field(description="quantiles at 32 evenly spaced levels")


class SeriesDetail(SeriesRef):
    component: str
    summaries: list[SummaryOut] = Field(description="per execution, in sort-key order")


class ExecutionDetail(BaseModel):
    id: int
    component: str
    revision: str
    sort_key: str
    job_id: int
    execution_index: int
    host: str | None
    sha256: str
    size: int
    created: datetime
    metadata: dict[str, Any]
    recording_pruned_at: datetime | None = Field(
        description="when retention deleted the raw recording; summaries are kept"
    )
    series: int = Field(description="how many series this execution summarized")


class ExecutionListed(BaseModel):
    """One execution in a component's list (``GET /api/v1/components/{name}/executions``)."""

    id: int
    revision: str
    sort_key: str
    job_id: int
    execution_index: int
    pair: int = Field(
        description="a confirmation run's pair (from 1, numbered on when the revision is judged "
        "again against another baseline and pairs are queued anew); 0 for the revision's own"
    )
    host: str | None
    state: str = Field(description="its job's state: uploaded (being ingested), done, failed")
    created: datetime
    duration_s: float | None = Field(
        description="from the run's start to its end as the agent (or an LNT report) recorded "
        "them; null when the run does not say"
    )
    size: int
    recording_pruned_at: datetime | None


class Statistics(BaseModel):
    n: int
    mean: float
    std: float
    min: float
    max: float
    p50: float = Field(description="median of the pooled samples (or of the sketches)")


class SeriesComparison(BaseModel):
    series: SeriesRef
    baseline: Statistics
    candidate: Statistics
    change: float | None = Field(description="relative change of the mean; null if undefined")
    ks_statistic: float = Field(description="two-sample KS D, 0..1")
    p_value: float
    exact: bool = Field(
        description="false when raw samples were pruned and the quantile sketches stood in for them"
    )


class Comparison(BaseModel):
    component: str
    base: str
    candidate: str
    base_revisions: list[str] = Field(
        default_factory=list, description="the revisions pooled as the baseline (a range a..b)"
    )
    candidate_revisions: list[str] = Field(
        default_factory=list, description="the revisions pooled as the candidate"
    )
    series: list[SeriesComparison]
