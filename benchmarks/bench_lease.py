"""Lease throughput over HTTP: 20 concurrent agents against one, on the same queue, same run.

A `redline server` process on real Postgres; 1,000 queued jobs (100 revisions x 10 executions).
One agent leases 500 of them alone, then 20 agents (threads, one HTTP client each) lease the
other 500 at once; every job must be leased exactly once. Figures: leases per second, and the
ratio of 20-agent to 1-agent throughput (SKIP LOCKED lets agents lease side by side; on a
2-core machine the server's one process is what saturates).

Run: .venv/bin/python benchmarks/bench_lease.py   (prints figures; not a test)
"""

from __future__ import annotations

import statistics
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

from _service import api_server, database
from redline.agent.client import ServerClient
from redline.server.db import session_factory
from redline.server.schemas.components import ComponentCreate
from redline.server.schemas.revisions import RevisionCreate
from redline.server.services.components import create_component
from redline.server.services.revisions import create_revision

REVISIONS, EXECUTIONS, AGENTS = 100, 10, 20
JOBS = REVISIONS * EXECUTIONS


def _queue(url: str) -> None:
    with session_factory(url)() as session:
        create_component(session, ComponentCreate(name="bench", executions=EXECUTIONS))
        for n in range(REVISIONS):
            create_revision(
                session,
                RevisionCreate(component="bench", title=f"r{n}", sort_key=str(n), commit="main"),
            )


def _agent(server: str, token: str, host: str, limit: int) -> tuple[list[int], list[float]]:
    client = ServerClient(server, token, host)
    client.register({}, [])
    leased, latencies = [], []
    try:
        while len(leased) < limit:
            start = time.perf_counter()
            job = client.lease()
            latencies.append(time.perf_counter() - start)
            if job is None:
                break
            leased.append(int(job["id"]))
    finally:
        client.close()
    return leased, latencies


def main() -> None:
    hosts = ("solo", *(f"agent-{n}" for n in range(AGENTS)))
    with database() as url, api_server(url, hosts=hosts) as (server, tokens):
        _queue(url)
        start = time.perf_counter()
        alone, alone_latency = _agent(server, tokens["agent@solo"], "solo", JOBS // 2)
        solo = len(alone) / (time.perf_counter() - start)
        start = time.perf_counter()
        with ThreadPoolExecutor(AGENTS) as pool:
            results = list(
                pool.map(
                    lambda n: _agent(server, tokens[f"agent@agent-{n}"], f"agent-{n}", JOBS),
                    range(AGENTS),
                )
            )
        crowd = sum(len(ids) for ids, _ in results) / (time.perf_counter() - start)
        counts = Counter(alone + [job for ids, _ in results for job in ids])
        assert len(counts) == JOBS and set(counts.values()) == {1}, "a job was leased twice"
        latency = [s for _, lat in results for s in lat]
        print(f"{JOBS} jobs, each leased once")
        print(
            f"1 agent: {solo:.0f} leases/s (median {statistics.median(alone_latency) * 1e3:.1f}"
            f" ms per lease)"
        )
        print(
            f"{AGENTS} agents: {crowd:.0f} leases/s (median "
            f"{statistics.median(latency) * 1e3:.1f} ms per lease)"
        )
        print(f"throughput {AGENTS} agents / 1 agent: {crowd / solo:.2f}x")


if __name__ == "__main__":
    main()
