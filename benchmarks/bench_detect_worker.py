"""The worker's detection on real (embedded) Postgres: one execution of 500 series, and a
re-analysis of a short history, with the default methods.

    nice -n 10 .venv/bin/python benchmarks/bench_detect_worker.py [--series 500] [--revisions 20]

Prints wall times and their ratio to the pure detectors over the same arrays (the database,
Parquet reads and grouping are the difference).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from redline.detect.config import DetectionConfig
from redline.recording import RecordingWriter
from redline.server.db import migrate, session_factory
from redline.server.embedded import start_postgres
from redline.server.models import Execution, JobState
from redline.server.schemas import ComponentCreate, RevisionCreate
from redline.server.services.components import create_component
from redline.server.services.revisions import create_revision
from redline.worker.detection import detect_revision
from redline.worker.ingest import ingest_execution
from redline.worker.reanalysis import reanalyze_component


def _recording(path: Path, job_id: int, title: str, series: int, rng: np.random.Generator,
               samples: int = 30) -> None:
    with RecordingWriter(path) as writer:
        writer.metadata("redline.run", {"job_id": str(job_id), "component": "bench",
                                        "revision_title": title, "revision_sort_key": title,
                                        "commit": "", "execution_index": "0"})
        writer.marker("begin", "case", "steady", {}, warmup=False, t_ns=1)
        for index in range(samples):
            values = {f"c{k}": float(v) for k, v in enumerate(rng.normal(20, 2, series))}
            writer.counters("component", 1, values, 10 + index * 10_000_000)
        writer.marker("end", "case", "steady", {}, warmup=False, t_ns=10**9)


def _history(url: str, folder: Path, series: int, revisions: int) -> tuple[int, list[int]]:
    rng = np.random.default_rng(0)
    execution_ids = []
    with session_factory(url)() as session:
        component = create_component(session, ComponentCreate(name="bench"))
        for number in range(1, revisions + 1):
            title = f"{number:04d}"
            revision = create_revision(session, RevisionCreate(component="bench", title=title,
                                                               sort_key=title))
            job = revision.jobs[0]
            path = folder / f"{title}.mcap"
            _recording(path, job.id, title, series, rng)
            execution = Execution(job_id=job.id, revision_id=revision.id,
                                  recording_path=str(path), sha256=title.ljust(64, "0"))
            job.state = JobState.uploaded
            session.add(execution)
            session.commit()
            execution_ids.append(execution.id)
        return component.id, execution_ids


def _pure(series: int) -> float:
    rng = np.random.default_rng(1)
    base, cand = rng.normal(20, 2, (series, 30)), rng.normal(20, 2, (series, 30))
    start = time.perf_counter()
    for detector in DetectionConfig().detectors():
        for k in range(series):
            detector.compare(base[k], cand[k])
    return time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--series", type=int, default=500)
    parser.add_argument("--revisions", type=int, default=20)
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="redline-bench-"))
    url, server = start_postgres(folder / "pg", "bench")
    try:
        migrate(url)
        component_id, executions = _history(url, folder, args.series, args.revisions)
        for execution_id in executions:
            ingest_execution(url, execution_id)
        with session_factory(url)() as session:
            last = session.get_one(Execution, executions[-1]).revision_id
        detect_revision(url, last)  # warm: imports, connections
        start = time.perf_counter()
        detect_revision(url, last)
        one = time.perf_counter() - start
        pure = _pure(args.series)
        methods = ", ".join(DetectionConfig().methods)
        print(f"one execution, {args.series} series x ({methods}): {one * 1000:.0f} ms "
              f"({one / pure:.1f}x the pure detectors' {pure * 1000:.0f} ms)")
        start = time.perf_counter()
        reanalyze_component(url, component_id)
        again = time.perf_counter() - start
        print(f"re-analysis of {args.revisions} revisions x {args.series} series: {again:.1f} s "
              f"({again / args.revisions * 1000:.0f} ms per revision)")
    finally:
        server.cleanup()
        shutil.rmtree(folder, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
