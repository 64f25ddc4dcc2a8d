"""Results imported without the SDK: Redline's generic results, and the answer to any import."""

from __future__ import annotations

from pydantic import BaseModel, Field, field_validator
from redline.recording.format import canonical_params
from redline.server.schemas.common import RequestBody
from redline.server.schemas.fields import (
    Commit,
    HostName,
    Line,
    Measure,
    ParamValue,
    SortKey,
    TestName,
    Title,
)


class ImportResult(BaseModel):
    component: str
    revision: str
    revision_id: int
    execution_id: int
    series: int = Field(description="series with a summary in this import")
    created: bool = Field(description="false when the same report was imported before")


class ResultValue(RequestBody):
    """One measured series of a generic result: its name and its samples."""

    case: TestName = Field(description="letters, digits, '_', '.' or '-', as the SDK's")
    phase: TestName = "main"
    params: dict[Line, ParamValue] = Field(
        default_factory=dict, description="each value text of one line, a number, true or false"
    )
    process: Line = "benchmark"
    counter: Line
    values: list[Measure] = Field(
        min_length=1,
        description="finite numbers within ±1e30 (NaN, infinities and text are refused)",
    )


class ResultsImport(RequestBody):
    """A benchmark's results without the SDK; see docs/api.md."""

    component: str = Field(min_length=1, max_length=200)
    revision: Title = Field(description="the revision's title")
    sort_key: SortKey
    commit: Commit = ""
    host: HostName = Field(default="", description="where it was measured")
    results: list[ResultValue] = Field(min_length=1)

    @field_validator("results")
    @classmethod
    def _each_series_once(cls, results: list[ResultValue]) -> list[ResultValue]:
        """One entry per series: a trial's two entries of one series were pooled without a
        word ([10] and [20] became one execution's mean of 15)."""
        first: dict[tuple, int] = {}
        for index, result in enumerate(results):
            params = canonical_params(result.params)
            key = (result.case, result.phase, params, result.process, result.counter)
            if key in first:
                raise ValueError(
                    f"results[{index}] is the series of results[{first[key]}] again (case, "
                    "phase, params, process and counter): give each series' values once"
                )
            first[key] = index
        return results
