"""The test driver's own metrics as series, beside the monitor's process counters.

The driver reports, per segment and per action of the tree, what it measured of the component
(`redline.testing`): FixedRate's achieved rate and lateness, Query's round trips, timeouts,
errors and unanswered queries, WaitFor's waits, Listen's rate and losses, Replay's lateness.
Each such field becomes a series of process `DRIVER_PROCESS`, named by the action's place in the
tree and the field: ``Sequence/Query(robot/get):rtt_p50_us``. One value per segment and
execution: detection judges them as it judges executions.

`DRIVER_METRICS` says which fields are measurements and which way each is worse. Counts of rare
events (timeouts, losses) are judged as counts out of the events they could have happened to
(``of``: queries sent, waits, samples expected), never as means of mostly-zero samples; those
totals are recorded too (`LOAD_FIELDS`), as the load the driver delivered, and are not judged.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from redline.recording.format import canonical_params

#: The process name of the driver's series (a component may not take it).
DRIVER_PROCESS = "driver"
#: The process name of the recorder's own counts (a run-wide segment, `RUN_CASE`).
RECORDER_PROCESS = "recorder"
#: The case and phase of series that belong to the whole run, not to one segment.
RUN_CASE, RUN_PHASE = "@run", "run"


@dataclass(frozen=True)
class Metric:
    """``worse``: ``"increase"`` when a higher value is worse, ``"decrease"`` when a lower one
    is (the `direction` a verdict names). ``of``:
    for a count of rare events, the fields it counts out of (the first one reported)."""

    worse: str
    of: tuple[str, ...] = ()

    @property
    def is_count(self) -> bool:
        return bool(self.of)


_HIGHER_WORSE = Metric("increase")
DRIVER_METRICS: dict[str, Metric] = {
    "rate_achieved": Metric("decrease"),  # FixedRate: iterations per second
    "rate": Metric("decrease"),  # Listen: samples received per second
    **{
        f"{measure}_{q}_us": _HIGHER_WORSE
        for measure in ("lateness", "rtt", "wait")
        for q in ("p50", "p90", "p99", "max")
    },
    "timeouts": Metric("increase", of=("queries", "waits")),
    "errors": Metric("increase", of=("queries",)),
    "unanswered": Metric("increase", of=("queries",)),
    "lost": Metric("increase", of=("expected", "sent")),
    "duplicates": Metric("increase", of=("received",)),
    "dropped": Metric("increase", of=("received",)),
}
#: The counts an action's tally reports only once they occur (0 otherwise), by action.
COUNTED_BY = {"Query": ("timeouts", "errors", "unanswered"), "WaitFor": ("timeouts",)}
#: How much the driver did (and what counts are out of): recorded, charted, not judged.
LOAD_FIELDS = (
    "queries",
    "waits",
    "expected",
    "received",
    "sent",
    "iterations",
    "messages",
    "count",
    "published",
)
#: The component's CPU per unit of work the driver delivered (a process counter, derived): a
#: run that delivered less load is not read as a faster component.
CPU_PER_OP = "cpu_us_per_op"
#: The same, in units of the host's reference work done beside it (the host counter
#: ``reference_us``, `redline.agent.sampling.REFERENCE`): a slower host at the time of a run
#: raises both, so their ratio keeps what the code changed (docs/detection.md).
CPU_REFS_PER_OP = "cpu_refs_per_op"
#: The host counter `CPU_REFS_PER_OP` divides by (the agent's `sampling.REFERENCE`).
HOST_REFERENCE = "reference_us"


def metric_of(counter: str) -> Metric | None:
    """The driver metric a driver series' counter names (``path:field``), None for a load."""
    return DRIVER_METRICS.get(counter.rpartition(":")[2])


def series_name(report: dict[str, Any]) -> str:
    """The report's action: its path, with the concrete key when the path does not show it."""
    path = str(report.get("path") or report.get("action") or "driver")
    key = report.get("key")
    return f"{path}[{key}]" if key and f"({key})" not in path else path


def report_values(report: dict[str, Any]) -> dict[str, float]:
    """The measurements and loads of one report, by field; a count its action's tally reports
    only when it occurs (`COUNTED_BY`) is 0 when the report does not name it."""
    values = {
        name: float(value)
        for name, value in report.items()
        if (name in DRIVER_METRICS or name in LOAD_FIELDS)
        and isinstance(value, int | float)
        and not isinstance(value, bool)
    }
    for name in COUNTED_BY.get(str(report.get("action")), ()):
        values.setdefault(name, 0.0)
    return values


def recorder_values(meta: dict[str, str]) -> dict[str, float]:
    """The recorder's own counts of the run (``redline.recorder`` metadata): samples lost on
    the way (out of those the driver ``sent``) and dropped by the recorder (out of those it
    ``received``)."""
    values: dict[str, float] = {}
    for name in ("lost", "sent", "dropped", "received"):
        try:
            values[name] = float(meta[name])
        except (KeyError, ValueError):
            continue
    return values


def segment_of(report: dict[str, Any], segments: Iterable[Any]) -> Any | None:
    """The segment a report was made in: same case, phase and parameters, and its time within
    the segment's markers (the driver reports just before the end marker)."""
    params, t_ns = canonical_params(report.get("params") or {}), report.get("t_ns", 0)
    for segment in segments:
        if (
            (segment.case, segment.phase) == (report.get("case"), report.get("phase"))
            and canonical_params(segment.params) == params
            and segment.begin_ns <= t_ns <= segment.end_ns
        ):
            return segment
    return None


#: the field of each action's report that counts the work it delivered (`work_done`)
WORK_FIELDS = {"Publish": "published", "Query": "count", "Replay": "messages"}


def work_done(reports: Iterable[dict[str, Any]]) -> float:
    """The units of work reports say the driver delivered: samples published (by `Publish` or
    replayed), queries answered. Not what `Listen` received: that is the component's output,
    judged by Listen's own rate and losses (counted here, a lost output would read as more CPU
    per unit of work, and an output per input would count the work twice)."""
    return float(
        sum(report.get(WORK_FIELDS.get(str(report.get("action")), ""), 0) for report in reports)
    )
