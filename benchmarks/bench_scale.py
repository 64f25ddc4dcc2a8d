"""Scale-out (issue 16): lease throughput with 1, 2 and 4 API processes, and ingestion throughput
with 1 and 2 Celery workers, each against a reference measured in the same run.

    .venv/bin/python benchmarks/bench_scale.py [--json OUT]

**Leases.** For each number of API processes (`redline server --workers N`), a fresh database
with 1,000 queued jobs (100 revisions x 10 executions) and 20 agents, each a process of its own
with one HTTP client, leasing until nothing is left; every job must be leased exactly once.
Leases per second, and the ratio to one process (goal: >= 1.7x with 2 on 2 cores).

**Ingestion.** 120 stored executions (20 series x 300 samples each) queued for ingestion, then
`redline worker --queues ingest` with 1, then 2 worker processes (`--concurrency`) until every
job is done: executions per minute, and the ratio of 2 to 1.

The re-analysis of 1,000 revisions x 100 series is one task today (not split by series), so more
workers do not shorten it: `benchmarks/bench_detect_worker.py` measures it.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from _service import api_server, database
from redline.agent.client import ServerClient
from redline.server.core.config import Settings
from redline.server.core.tasks import TaskSender
from redline.server.db import session_factory
from redline.server.models import Job, JobState
from redline.server.schemas.components import ComponentCreate
from redline.server.schemas.revisions import RevisionCreate
from redline.server.services.components import create_component
from redline.server.services.revisions import create_revision
from sqlalchemy import func, select

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.support.history import add_execution  # noqa: E402

REVISIONS, EXECUTIONS, AGENTS = 100, 10, 20
JOBS = REVISIONS * EXECUTIONS
INGESTED, SERIES = 120, 20
REDLINE = str(Path(sys.executable).parent / "redline")


def _lease_all(args: tuple[str, str, str]) -> list[int]:
    server, token, host = args
    client = ServerClient(server, token, host)
    client.register({}, [])
    leased = []
    try:
        while (job := client.lease()) is not None:
            leased.append(int(job["id"]))
    finally:
        client.close()
    return leased


def leases(processes: int) -> float:
    with database() as url, api_server(url, workers=processes) as (server, tokens):
        with session_factory(url)() as session:
            create_component(session, ComponentCreate(name="bench", executions=EXECUTIONS))
            for n in range(REVISIONS):
                create_revision(
                    session,
                    RevisionCreate(
                        component="bench", title=f"r{n}", sort_key=str(n), commit="main"
                    ),
                )
        agents = [(server, tokens["agent"], f"agent-{n}") for n in range(AGENTS)]
        with multiprocessing.get_context("spawn").Pool(AGENTS) as pool:
            pool.map(time.sleep, [0.0] * AGENTS)  # the agents' processes are up
            start = time.perf_counter()
            results = pool.map(_lease_all, agents, chunksize=1)
            seconds = time.perf_counter() - start
    counts = Counter(job for ids in results for job in ids)
    assert len(counts) == JOBS and set(counts.values()) == {1}, "a job was leased twice or never"
    return JOBS / seconds


def ingestion(workers: int) -> float:
    with database() as url, tempfile.TemporaryDirectory(prefix="bench-scale-") as tmp:
        folder = Path(tmp)
        settings = Settings(
            database_url=url,
            redis_url=os.environ.get("REDLINE_REDIS_URL", "redis://127.0.0.1:6379/0"),
            queue=f"bench-scale-{os.getpid()}-{workers}",
            storage_dir=folder / "storage",
        )
        rng = np.random.default_rng(workers)
        with session_factory(url)() as session:
            create_component(session, ComponentCreate(name="builder"))
            executions = [
                add_execution(
                    session,
                    folder,
                    "builder",
                    f"r{n}",
                    f"{n:04d}",
                    {f"c{s}": rng.normal(10, 1, 300) for s in range(SERIES)},
                )  # fmt: skip
                for n in range(INGESTED)
            ]
        sender = TaskSender(settings)
        for execution in executions:
            sender.ingest(execution.id)
        env = {
            **os.environ,
            "REDLINE_DATABASE_URL": url,
            "REDLINE_REDIS_URL": settings.redis_url,
            "REDLINE_QUEUE": settings.queue,
            "REDLINE_STORAGE_DIR": str(settings.storage_dir),
        }
        start = time.perf_counter()
        worker = subprocess.Popen(
            [REDLINE, "worker", "--queues", "ingest", "--no-beat", "--concurrency", str(workers),
             "--loglevel", "WARNING"],
            env=env, start_new_session=True,
        )  # fmt: skip
        try:
            while True:
                with session_factory(url)() as session:
                    done = session.scalar(
                        select(func.count()).where(Job.state.in_([JobState.done, JobState.failed]))
                    )
                if done >= INGESTED:
                    break
                time.sleep(0.2)
            seconds = time.perf_counter() - start
        finally:
            os.killpg(worker.pid, 15)
            worker.wait(timeout=60)
        with session_factory(url)() as session:
            failed = session.scalar(select(func.count()).where(Job.state == JobState.failed))
        assert not failed, f"{failed} ingestion(s) failed"
        shutil.rmtree(folder / "storage", ignore_errors=True)
    return INGESTED / seconds * 60


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    report: dict[str, dict[str, float]] = {"leases_per_s": {}, "ingested_per_min": {}}
    for processes in (1, 2, 4):
        report["leases_per_s"][str(processes)] = rate = leases(processes)
        print(f"{processes} API process(es), {AGENTS} agents: {rate:.0f} leases/s", flush=True)
    one = report["leases_per_s"]["1"]
    for processes in ("2", "4"):
        print(f"  {processes} / 1 process(es): {report['leases_per_s'][processes] / one:.2f}x")
    for workers in (1, 2):
        report["ingested_per_min"][str(workers)] = rate = ingestion(workers)
        print(f"{workers} ingest worker process(es): {rate:.0f} executions/min", flush=True)
    ratio = report["ingested_per_min"]["2"] / report["ingested_per_min"]["1"]
    print(f"  2 / 1 worker(s): {ratio:.2f}x")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
