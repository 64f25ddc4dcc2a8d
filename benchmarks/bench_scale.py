"""Scale-out (issue 16): lease throughput with 1, 2 and 4 API processes, and ingestion throughput
with 1 and 2 Celery workers, each against a reference measured in the same run.

    .venv/bin/python benchmarks/bench_scale.py [--json OUT]

**Leases.** For each number of API processes (`redline server --workers N`), a fresh database
with 1,000 queued jobs (100 revisions x 10 executions) and 20 agents, each a process of its own
with one HTTP client, leasing until nothing is left; every job must be leased exactly once.
Leases per second, and the ratio to one process (goal: >= 1.7x with 2 on 2 cores). Beside each
rate, who used the cores while the agents leased: CPU seconds of the API's processes, the
agents', Postgres's (the postmaster and its backends; an embedded Postgres, or one on this
host), this benchmark's own, and the rest of the host's busy time (others' processes: a host
that was not quiet shows here), with the 1-minute load average as the run began.

**Ingestion.** 120 stored executions (20 series x 300 samples each) queued for ingestion, then
`redline worker --queues ingest` with 1, then 2 worker processes (`--concurrency`) until every
job is done: executions per minute, and the ratio of 2 to 1.

**Re-analysis.** A history of 1,000 revisions x 100 series (one execution of 30 samples each,
the default methods), ingested once; then the re-analysis task sent and timed until its row says
done, by a `redline worker --queues detect` with 1 process and the re-analysis in 1 part (the
reference: one walk, as before it was split), with 1 process and 2 parts (what splitting costs
a worker alone), and with 2 processes and 2 parts (goal: <= 30 s). The verdicts of every run
must be the same.

    .venv/bin/python benchmarks/bench_scale.py --only reanalysis
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
import psutil
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


def _lease_all(args: tuple[str, str, str]) -> tuple[list[int], float]:
    """The jobs one agent leased until none was left, and the CPU seconds it spent on them."""
    server, token, host = args
    began = time.process_time()
    client = ServerClient(server, token, host)
    client.register({}, [])
    leased = []
    try:
        while (job := client.lease()) is not None:
            leased.append(int(job["id"]))
    finally:
        client.close()
    return leased, time.process_time() - began


def _tree_cpu(root: psutil.Process | None) -> float:
    """CPU seconds the processes under ``root`` have used so far: each live one's own and that of
    its children it has reaped (a Postgres backend that ended counts in the postmaster's)."""
    if root is None:
        return 0.0
    total = 0.0
    for process in [root, *root.children(recursive=True)]:
        try:
            used = process.cpu_times()
        except psutil.NoSuchProcess:  # ended between the listing and now: in its parent's
            continue
        total += used.user + used.system + used.children_user + used.children_system
    return total


def _api_process(port: str) -> psutil.Process:
    """The `redline server` this benchmark started on ``port`` (its API processes are children)."""
    for child in psutil.Process().children():
        command = child.cmdline()
        if "server" in command and port in command:
            return child
    raise RuntimeError(f"no `redline server --port {port}` among this benchmark's children")


def _postmaster(url: str) -> psutil.Process | None:
    """The Postgres server of ``url`` when it runs on this host (a backend's parent), else None.
    Every backend of it counts, other users' too: measure on the embedded one (no
    ``REDLINE_DATABASE_URL``) for the benchmark's alone."""
    with session_factory(url)() as session:
        backend = session.scalar(select(func.pg_backend_pid()))
    try:
        process = psutil.Process(backend)
        return process.parent() if process.name().startswith("postgres") else None
    except psutil.NoSuchProcess:  # on another host: not counted
        return None


class CpuSplit:
    """Who used this host's cores between `start` and `stop`, in CPU seconds."""

    def __init__(self, api: psutil.Process, postgres: psutil.Process | None) -> None:
        self.api, self.postgres = api, postgres

    def _read(self) -> tuple[float, ...]:
        host = psutil.cpu_times()  # Linux counts guest time in user time already
        busy = host.user + host.nice + host.system  # what processes ran
        # interrupts (the loopback network's softirq among them) are no process's; idle; and
        # steal: the hypervisor ran other machines
        interrupts, idle, steal = host.irq + host.softirq, host.idle + host.iowait, host.steal
        api, postgres = _tree_cpu(self.api), _tree_cpu(self.postgres)
        return busy, interrupts, idle, steal, api, postgres, time.process_time()

    def start(self) -> None:
        self.before, self.began = self._read(), time.perf_counter()

    def stop(self, agents: float) -> dict[str, float]:
        after, seconds = self._read(), time.perf_counter() - self.began
        busy, interrupts, idle, steal, api, postgres, own = (
            b - a for a, b in zip(self.before, after, strict=True)
        )
        return {
            "seconds": seconds,
            "cores": float(psutil.cpu_count() or 0),
            "api": api,
            "agents": agents,
            "postgres": postgres,
            "benchmark": own,
            "others": busy - api - agents - postgres - own,
            "interrupts": interrupts,
            "idle": idle,
            "steal": steal,
        }


def leases(processes: int) -> tuple[float, dict[str, float]]:
    """Leases per second with ``processes`` API processes, and who used the cores meanwhile
    (with the 1-minute load average before this run started anything: its 20 agents' start
    raises it by several)."""
    load = os.getloadavg()[0]
    hosts = tuple(f"agent-{n}" for n in range(AGENTS))
    with database() as url, api_server(url, workers=processes, hosts=hosts) as (server, tokens):
        with session_factory(url)() as session:
            create_component(session, ComponentCreate(name="bench", executions=EXECUTIONS))
            for n in range(REVISIONS):
                create_revision(
                    session,
                    RevisionCreate(
                        component="bench", title=f"r{n}", sort_key=str(n), commit="main"
                    ),
                )
        split = CpuSplit(_api_process(server.rsplit(":", 1)[1]), _postmaster(url))
        agents = [(server, tokens[f"agent@{host}"], host) for host in hosts]
        with multiprocessing.get_context("spawn").Pool(AGENTS) as pool:
            pool.map(time.sleep, [0.0] * AGENTS)  # the agents' processes are up
            split.start()
            results = pool.map(_lease_all, agents, chunksize=1)
            cpu = split.stop(sum(spent for _, spent in results))
    counts = Counter(job for ids, _ in results for job in ids)
    assert len(counts) == JOBS and set(counts.values()) == {1}, "a job was leased twice or never"
    return JOBS / cpu["seconds"], {"load_1min_before": load, **cpu}


#: others' share of the cores over which a lease run was not on a quiet host
NOT_QUIET = 0.10


def _print_split(cpu: dict[str, float]) -> None:
    groups = ("api", "agents", "postgres", "benchmark", "others", "interrupts", "idle", "steal")
    print(
        f"  CPU s over {cpu['seconds']:.1f} s x {cpu['cores']:.0f} cores "
        f"(load {cpu['load_1min_before']:.2f} before): "
        + ", ".join(f"{name} {cpu[name]:.1f}" for name in groups),
        flush=True,
    )
    if (share := cpu["others"] / (cpu["seconds"] * cpu["cores"])) > NOT_QUIET:
        print(f"  NOT QUIET: other processes used {share:.0%} of the cores", flush=True)


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
        env = _worker_env(settings)
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


def _worker_env(settings: Settings) -> dict[str, str]:
    """A `redline worker`'s environment: this run's database, Redis, queue and storage."""
    return {
        **os.environ,
        "REDLINE_DATABASE_URL": settings.database_url,
        "REDLINE_REDIS_URL": settings.redis_url,
        "REDLINE_QUEUE": settings.queue,
        "REDLINE_STORAGE_DIR": str(settings.storage_dir),
    }


def _worker(env: dict[str, str], queues: str, processes: int, log: Path) -> subprocess.Popen:
    """`redline worker` taking ``queues``, once it says it is ready."""
    worker = subprocess.Popen(
        [REDLINE, "worker", "--queues", queues, "--no-beat", "--concurrency", str(processes),
         "--loglevel", "INFO"],
        env=env, start_new_session=True, stdout=log.open("ab"), stderr=subprocess.STDOUT,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while " ready." not in log.read_text(errors="replace"):
        if time.monotonic() > deadline or worker.poll() is not None:
            os.killpg(worker.pid, 9)
            raise RuntimeError(f"the worker did not start: {log.read_text()[-2000:]}")
        time.sleep(0.1)
    return worker


def reanalysis(runs: list[tuple[int, int]]) -> dict[str, float]:
    """Seconds of a re-analysis of 1,000 x 100 for each (worker processes, parts) in ``runs``."""
    from bench_detect_worker import _history, _ingest
    from redline.server.models import Detection, Reanalysis

    seconds: dict[str, float] = {}
    with database() as url, tempfile.TemporaryDirectory(prefix="bench-scale-") as tmp:
        folder = Path(tmp)
        start = time.perf_counter()
        component_id, executions = _history(url, folder, "history", 100, 1000)
        _ingest(url, executions)
        print(f"history of 1,000 x 100 ingested in {time.perf_counter() - start:.0f} s", flush=True)
        verdicts = []
        for processes, parts in runs:
            settings = Settings(
                database_url=url,
                redis_url=os.environ.get("REDLINE_REDIS_URL", "redis://127.0.0.1:6379/0"),
                queue=f"bench-reanalysis-{os.getpid()}-{processes}-{parts}",
                storage_dir=folder / "storage",
            )
            env = {**_worker_env(settings), "REDLINE_REANALYSIS_PARTS": str(parts)}
            worker = _worker(env, "detect", processes, folder / f"worker-{processes}-{parts}.log")
            with session_factory(url)() as session:
                row = session.get(Reanalysis, component_id)
                before = row.run if row is not None else 0
            try:
                start = time.perf_counter()
                TaskSender(settings).reanalyze(component_id)
                while True:
                    with session_factory(url)() as session:
                        row = session.get(Reanalysis, component_id)
                        state = row.state if row is not None and row.run > before else "queued"
                    if state in ("done", "failed"):
                        break
                    time.sleep(0.1)
                took = time.perf_counter() - start
            finally:
                os.killpg(worker.pid, 15)
                worker.wait(timeout=60)
            assert state == "done", f"the re-analysis failed: {row.error if row else ''}"
            with session_factory(url)() as session:
                verdicts.append(
                    session.execute(
                        select(Detection.series_id, Detection.revision_id, Detection.method,
                               Detection.verdict, Detection.score)
                        .order_by(Detection.series_id, Detection.revision_id, Detection.method)
                    ).all()
                )  # fmt: skip
            seconds[f"{processes} process(es), {parts} part(s)"] = took
            print(f"re-analysis, {processes} worker process(es), {parts} part(s): {took:.1f} s",
                  flush=True)  # fmt: skip
        assert all(v == verdicts[0] for v in verdicts), "the runs' verdicts differ"
    return seconds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", type=Path)
    parser.add_argument("--only", choices=["leases", "ingestion", "reanalysis"])
    args = parser.parse_args()
    report: dict[str, dict] = {}
    if args.only in (None, "reanalysis"):
        report["reanalysis_s"] = times = reanalysis([(1, 1), (1, 2), (2, 2)])
        reference = times["1 process(es), 1 part(s)"]
        for name, took in times.items():
            print(f"  {name}: {took / reference:.2f}x the one walk's {reference:.1f} s")
    if args.only in (None, "leases"):
        report["leases_per_s"], report["lease_cpu_s"] = {}, {}
        for processes in (1, 2, 4):
            rate, cpu = leases(processes)
            report["leases_per_s"][str(processes)] = rate
            report["lease_cpu_s"][str(processes)] = cpu
            print(f"{processes} API process(es), {AGENTS} agents: {rate:.0f} leases/s", flush=True)
            _print_split(cpu)
        one = report["leases_per_s"]["1"]
        for processes in ("2", "4"):
            print(f"  {processes} / 1 process(es): {report['leases_per_s'][processes] / one:.2f}x")
    if args.only in (None, "ingestion"):
        report["ingested_per_min"] = {}
        for workers in (1, 2):
            report["ingested_per_min"][str(workers)] = rate = ingestion(workers)
            print(f"{workers} ingest worker process(es): {rate:.0f} executions/min", flush=True)
        ratio = report["ingested_per_min"]["2"] / report["ingested_per_min"]["1"]
        print(f"  2 / 1 worker(s): {ratio:.2f}x")
    _write(args.json, report)
    return 0


def _measured_at() -> str:
    """The code measured: this checkout's commit, and how many of Redline's source files differ
    from it (the tree may hold uncommitted changes), with the date."""

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True).stdout

    changed = git("status", "--porcelain", "--", "agent/src", "server/src").splitlines()
    return (
        f"{git('rev-parse', '--short', 'HEAD').strip()}"
        + (f" + {len(changed)} uncommitted source file(s)" if changed else "")
        + time.strftime(", %Y-%m-%d %H:%M UTC", time.gmtime())
    )


def _write(path: Path | None, report: dict) -> None:
    """The figures into ``path``, merged with those an earlier run of other parts wrote, each
    part with the code and time it was measured at (``measured``)."""
    if path:
        earlier = json.loads(path.read_text()) if path.exists() else {}
        at = _measured_at()
        measured = earlier.get("measured", {}) | dict.fromkeys(report, at)
        path.write_text(json.dumps(earlier | report | {"measured": measured}, indent=1))


if __name__ == "__main__":
    sys.exit(main())
