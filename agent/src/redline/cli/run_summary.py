"""What `redline run` prints after a run: per segment, each process's CPU, memory and threads, and
what the driver measured of the component (rates, round trips, timeouts, losses)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence

from redline.recording import HOST_PROCESS, SeriesKey, params_name
from redline.recording.driver import DRIVER_PROCESS, RECORDER_PROCESS, RUN_CASE
from rich.markup import escape
from rich.table import Table

Samples = Mapping[SeriesKey, Sequence[float]]
#: the driver's fields shown, in order, with how to show one value
_SHOWN = (
    ("rate_achieved", "{:.1f}/s achieved"),
    ("rate", "{:.1f}/s received"),
    ("rtt_p50_us", "rtt p50 {:.0f} µs"),
    ("rtt_p99_us", "p99 {:.0f} µs"),
    ("wait_p50_us", "wait p50 {:.0f} µs"),
    ("wait_p99_us", "p99 {:.0f} µs"),
    ("lateness_p99_us", "lateness p99 {:.0f} µs"),
)
#: how much an action did, shown when it measured nothing else (a Publish: its count)
_DONE = (
    ("published", "{:.0f} published"),
    ("messages", "{:.0f} messages replayed"),
    ("received", "{:.0f} received"),
    ("sent", "{:.0f} sent"),
)
#: counts of rare events, shown out of their totals
_COUNTED = (
    ("timeouts", ("queries", "waits")),
    ("errors", ("queries",)),
    ("unanswered", ("queries",)),
    ("lost", ("expected", "sent")),
    ("dropped", ("received",)),
)


def _segment(key: SeriesKey) -> str:
    if key.case == RUN_CASE:
        return "the whole run"
    return f"{key.case}/{key.phase} [{params_name(json.loads(key.params))}]"


def process_table(samples: Samples) -> Table:
    """Per segment and process: mean CPU, peak RSS and threads."""
    rows: dict[tuple[str, str], dict[str, Sequence[float]]] = {}
    for key, values in samples.items():
        if key.process not in (DRIVER_PROCESS, RECORDER_PROCESS):
            rows.setdefault((_segment(key), key.process), {})[key.counter] = values
    table = Table("segment", "process", "cpu % (mean)", "rss MiB (max)", "threads (max)")
    for (segment, process), counters in rows.items():
        cpu, rss = counters.get("cpu_percent", []), counters.get("rss_bytes", [])
        threads = counters.get("threads", [])
        table.add_row(
            escape(segment),
            escape(process) + (" (context)" if process == HOST_PROCESS else ""),
            f"{sum(cpu) / len(cpu):.1f}" if cpu else "-",
            f"{max(rss) / 2**20:.1f}" if rss else "-",
            f"{max(threads):.0f}" if threads else "-",
        )
    return table


def measured(fields: Mapping[str, float]) -> str:
    """One action's measurements in a line: ``rtt p50 590 µs, p99 1200 µs, 3 of 4217
    timeouts``; for one that measured nothing, what it did (``400 published``: a row of "-"
    read as a Publish that failed)."""
    parts = [form.format(fields[name]) for name, form in _SHOWN if name in fields]
    for name, totals in _COUNTED:
        total = next((fields[t] for t in totals if t in fields), None)
        if name in fields and total is not None:
            parts.append(f"{fields[name]:.0f} of {total:.0f} {name}")
        elif fields.get(name):  # out of nothing counted: said, and why it is not judged
            parts.append(f"{fields[name]:.0f} {name} (out of no {' or '.join(totals)} counted: "
                         "not judged)")  # fmt: skip
    if not parts:
        parts = [form.format(fields[name]) for name, form in _DONE if name in fields]
    return ", ".join(parts) or "-"


def driver_table(samples: Samples) -> Table | None:
    """Per segment and action: what the driver (and the recorder) measured; None when nothing."""
    rows: dict[tuple[str, str], dict[str, float]] = {}
    for key, values in samples.items():
        if key.process in (DRIVER_PROCESS, RECORDER_PROCESS) and values:
            action, _, field_name = key.counter.rpartition(":")
            row = rows.setdefault((_segment(key), action or key.process), {})
            row[field_name] = sum(values)  # one value per segment and recording
    if not rows:
        return None
    table = Table("segment", "action", "measured")
    for (segment, action), fields in rows.items():
        table.add_row(escape(segment), escape(action), escape(measured(fields)))
    return table
