"""One execution as its page shows it (the paper's plots, its section 4.4.2): the raw counters of
the component's processes against time with the phases marked, each counter against each
numeric test parameter, the driver's metrics, and the output of the component's processes.

The raw counters come from the stored recording (gone once retention pruned it: the page says
so); the rest from the execution's summaries, which stay.
"""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

from redline.detect.counters import kind
from redline.recording import RecordingError, Segment, read_recording
from redline.server.models import Execution, Series, Summary
from redline.server.schemas.results import ExecutionDetail
from redline.server.services.errors import NotFound
from redline.server.services.read import execution_detail
from sqlalchemy import select
from sqlalchemy.orm import Session


@dataclass(frozen=True)
class SummaryRow:
    case: str
    phase: str
    params: dict[str, object]
    process: str
    counter: str
    kind: str
    n: int
    mean: float
    p50: float
    p95: float


@dataclass
class ExecutionView:
    detail: ExecutionDetail
    recording: Path | None  # None when pruned or missing
    why_no_recording: str
    segments: list[Segment] = field(default_factory=list)
    #: (process, counter) -> [(seconds since the first sample, value)], the component's own
    timelines: dict[tuple[str, str], list[tuple[float, float]]] = field(default_factory=dict)
    start_ns: int = 0
    summaries: list[SummaryRow] = field(default_factory=list)
    #: each component or fixture process's output (its end), by process name
    logs: dict[str, str] = field(default_factory=dict)


def _summaries(session: Session, execution_id: int) -> list[SummaryRow]:
    rows = session.execute(
        select(Series, Summary.n, Summary.mean, Summary.p50, Summary.p95)
        .join(Summary, Summary.series_id == Series.id)
        .where(Summary.execution_id == execution_id)
        .order_by(Series.case, Series.phase, Series.process, Series.counter, Series.params)
    )
    return [
        SummaryRow(
            s.case, s.phase, json.loads(s.params), s.process, s.counter, kind(s.process), n,
            mean, p50, p95
        )
        for s, n, mean, p50, p95 in rows
    ]  # fmt: skip


def recording_file(session: Session, execution_id: int) -> tuple[Path | None, str]:
    """The execution's stored recording, or None and why there is none; NotFound naming an
    unknown execution."""
    execution = session.get(Execution, execution_id)
    if execution is None:
        raise NotFound(f"unknown execution {execution_id}")
    if execution.pruned_at is not None:
        return None, f"the raw recording was pruned on {execution.pruned_at:%Y-%m-%d}"
    path = Path(execution.recording_path) if execution.recording_path else None
    if path is None or path.suffix != ".mcap" or not path.is_file():
        return None, "no raw recording is stored for it (an import)"
    return path, ""


def execution_view(session: Session, execution_id: int) -> ExecutionView:
    detail = execution_detail(session, execution_id)
    path, why = recording_file(session, execution_id)
    view = ExecutionView(detail, None, why, summaries=_summaries(session, execution_id))
    if path is None:
        return view
    try:
        recording = read_recording(path, strict=False)
    except (OSError, RecordingError) as exc:
        view.why_no_recording = f"its recording cannot be read: {exc}"
        return view
    view.recording = path
    view.segments = recording.segments()
    view.logs = dict(sorted(recording.logs.items()))
    lines: dict[tuple[str, str], list[tuple[int, float]]] = defaultdict(list)
    for key, points in recording.series_timeline(include_warmup=True).items():
        if kind(key.process) == "counter":
            lines[(key.process, key.counter)].extend(points)
    first = min((t for points in lines.values() for t, _ in points), default=0)
    view.start_ns = first
    view.timelines = {
        name: [((t - first) / 1e9, value) for t, value in sorted(points)]
        for name, points in sorted(lines.items())
    }
    return view
