"""Finished Redline recordings written by the real RecordingWriter, as a run would make them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from redline.recording import RecordingWriter
from redline.server.models import Job

CASE, PHASE, PARAMS, PROCESS = "throughput", "publish", {"rate": 10}, "component"


def write_recording(
    path: Path,
    run: dict[str, str],
    counters: dict[str, np.ndarray],
    *,
    warmup: dict[str, np.ndarray] | None = None,
    process: str = PROCESS,
    host_percent: float | None = None,
    extra: tuple[str, bytes] | None = None,
) -> Path:
    """A finished Redline recording: one segment per phase, one counter sample per 10 ms;
    with ``host_percent``, the host's CPU (% of its 2 cores) and Redline's own beside each
    sample (`redline.recording.disturbance`); with ``extra``, one more message (topic, bytes)
    written as given, after them."""
    with RecordingWriter(path) as writer:
        writer.metadata("redline.run", run)
        if host_percent is not None:
            writer.metadata("redline.host", {"cpu_cores": "2"})
        t_ns = 1_000_000_000
        for phase, values, is_warmup in (("warmup", warmup, True), (PHASE, counters, False)):
            if values is None:
                continue
            writer.marker("begin", CASE, phase, PARAMS, warmup=is_warmup, t_ns=t_ns)
            for index in range(len(next(iter(values.values())))):
                t_ns += 10_000_000
                sample = {name: float(column[index]) for name, column in values.items()}
                writer.counters(process, 4242, sample, t_ns)
                if host_percent is not None:  # with Redline's own share, to tell the other
                    writer.counters("host", 0, {"cpu_percent": host_percent}, t_ns)
                    writer.counters("redline", 0, {"cpu_percent": 4.0}, t_ns)
            t_ns += 10_000_000
            writer.marker("end", CASE, phase, PARAMS, warmup=is_warmup, t_ns=t_ns)
        if extra is not None:
            writer.write(extra[0], extra[1], encoding="json", t_ns=t_ns)
    return path


def run_metadata(
    job: Job, component: str, title: str, sort_key: str, commit: str = ""
) -> dict[str, str]:
    return {
        "job_id": str(job.id),
        "component": component,
        "revision_title": title,
        "revision_sort_key": sort_key,
        "commit": commit,
        "execution_index": str(job.execution_index),
    }
