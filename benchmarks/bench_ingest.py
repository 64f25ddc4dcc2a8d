"""Ingest of a 10-minute recording against just reading its MCAP file, in the same run.

The recording is synthesized with RecordingWriter: 10 minutes at 10 Hz, 5 processes with 12
counters each (30,000 counter messages: three components, the host and Redline's own processes,
so the other load of each phase is derived), 10 one-minute segments with the driver's reports of
a tree of 6 actions each (queries with round-trip quantiles and timeouts, fixed rates, a
listener with losses: 60 driver series), and zenoh traffic up to 100,000 messages in all.
"Read" decompresses and walks every MCAP record (mcap's StreamReader, no decoding); "ingest" is
`ingest_execution` on real Postgres: strict read, series, summaries, Parquet samples, job marked
done. The target is ingest <= 3x read.

Run: .venv/bin/python benchmarks/bench_ingest.py   (prints figures; not a test)
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from _service import database
from mcap.stream_reader import StreamReader
from redline.recording import RecordingWriter
from redline.server.db import session_factory
from redline.server.models import Execution, JobState
from redline.server.schemas.components import ComponentCreate
from redline.server.schemas.revisions import RevisionCreate
from redline.server.services.components import create_component
from redline.server.services.revisions import create_revision
from redline.worker.ingest import ingest_execution

MINUTES, RATE, PROCESSES, COUNTERS, MESSAGES, SEGMENTS = 10, 10, 5, 12, 100_000, 10
REPEATS = 5
COUNTER_NAMES = ["cpu_percent", *(f"counter_{n:02d}" for n in range(1, COUNTERS))]
PROCESS_NAMES = ["proc0", "proc1", "proc2", "host", "redline"]
REPORTS = [  # the driver's reports at each segment's end: what a tree of 6 actions measures
    *(
        {
            "action": "Query",
            "path": f"FixedRate/Query(svc/q{n})",
            "key": f"svc/q{n}",
            "queries": 600,
            "count": 598,
            "timeouts": 2,
            "rtt_p50_us": 500.0,
            "rtt_p90_us": 700.0,
            "rtt_p99_us": 900.0,
            "rtt_max_us": 2000.0,
        }
        for n in range(3)
    ),
    *(
        {
            "action": "FixedRate",
            "path": f"Parallel/FixedRate#{n}",
            "rate_target": 10.0,
            "rate_achieved": 9.98,
            "iterations": 600,
            "lateness_p50_us": 80.0,
            "lateness_p99_us": 400.0,
            "lateness_max_us": 900.0,
        }
        for n in range(2)
    ),
    {
        "action": "Listen",
        "path": "Listen(svc/out)",
        "key": "svc/out",
        "received": 590,
        "expected": 600,
        "lost": 10,
        "rate": 9.8,
    },
]


def synthesize(path: Path, run: dict[str, str]) -> int:
    """Write the recording; returns its number of messages."""
    rng = np.random.default_rng(7)
    ticks = MINUTES * 60 * RATE
    counter_messages = ticks * PROCESSES
    traffic = MESSAGES - counter_messages - 2 * SEGMENTS
    per_tick = np.diff(np.linspace(0, traffic, ticks + 1).astype(int))
    values = rng.normal(50.0, 5.0, (ticks, PROCESSES, COUNTERS))
    payload = bytes(64)
    t0, step = 1_000_000_000, 1_000_000_000 // RATE
    with RecordingWriter(path) as writer:
        writer.metadata("redline.run", run)
        writer.metadata("redline.host", {"cpu_cores": "2"})
        for tick in range(ticks):
            t_ns = t0 + tick * step
            segment, offset = divmod(tick, ticks // SEGMENTS)
            params = {"rate": 10 * (segment + 1)}
            if offset == 0:
                writer.marker("begin", "load", "steady", params, t_ns=t_ns - 1)
            for process in range(PROCESSES):
                writer.counters(
                    PROCESS_NAMES[process],
                    100 + process,
                    dict(zip(COUNTER_NAMES, values[tick, process].tolist(), strict=True)),
                    t_ns,
                )
            for n in range(per_tick[tick]):
                writer.write(f"bench/topic{n % 4}", payload, t_ns=t_ns + n + 1)
            if offset == ticks // SEGMENTS - 1:
                for report in REPORTS:
                    writer.write_json(
                        "@redline/driver/load/steady",
                        {
                            "t_ns": t_ns + step - 2,
                            "case": "load",
                            "phase": "steady",
                            "params": params,
                            **report,
                        },
                    )
                writer.marker("end", "load", "steady", params, t_ns=t_ns + step - 1)
        return writer.messages


def read_only(path: Path) -> int:
    with open(path, "rb") as stream:
        return sum(1 for _ in StreamReader(stream, skip_magic=False).records)


def _execution(url: str, folder: Path) -> tuple[int, int]:
    with session_factory(url)() as session:
        create_component(session, ComponentCreate(name="bench"))
        revision = create_revision(
            session, RevisionCreate(component="bench", title="r1", sort_key="1", commit="main")
        )
        job = revision.jobs[0]
        path = folder / "r1.mcap"
        count = synthesize(
            path,
            {
                "job_id": str(job.id),
                "component": "bench",
                "revision_title": "r1",
                "revision_sort_key": "1",
                "execution_index": "0",
            },
        )
        execution = Execution(
            job_id=job.id,
            revision_id=revision.id,
            recording_path=str(path),
            sha256="bench".ljust(64, "0"),
            size=path.stat().st_size,
        )
        job.state = JobState.uploaded
        session.add(execution)
        session.commit()
        return execution.id, count


def _timed(action) -> float:  # noqa: ANN001 - a no-argument callable
    start = time.perf_counter()
    action()
    return time.perf_counter() - start


def main() -> None:
    with database() as url, tempfile.TemporaryDirectory() as tmp:
        execution, count = _execution(url, Path(tmp))
        size = (Path(tmp) / "r1.mcap").stat().st_size
        print(f"recording: {count} messages, {size / 1e6:.1f} MB")
        reads, ingests = [], []
        for _ in range(REPEATS):  # interleaved, so that other load hits both alike
            reads.append(_timed(lambda: read_only(Path(tmp) / "r1.mcap")))
            ingests.append(_timed(lambda: ingest_execution(url, execution)))
        read, ingest = statistics.median(reads), statistics.median(ingests)
        ratios = [i / r for i, r in zip(ingests, reads, strict=True)]
        print(f"read MCAP: median {read * 1e3:.0f} ms; ingest: median {ingest * 1e3:.0f} ms")
        print(
            f"ingest / read: {ingest / read:.2f}x (per-pair median "
            f"{statistics.median(ratios):.2f}x; target <= 3x)"
        )


if __name__ == "__main__":
    main()
