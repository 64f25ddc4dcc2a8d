"""Verdicts end to end: the real service over a git history with injected changes.

    .venv/bin/python benchmarks/bench_verdicts.py [--pairs 3] [--stretch 6] [--json FILE]

Run it on a quiet host (it makes its own noise). It builds a git repository of
``examples/objectbuilder`` whose history has stretches of unchanged revisions (only a comment in
``tuning.py`` differs) and, between them, one injected change each (`EVENTS`): CPU +5 % (twice),
+10 %, +30 %, a round trip about 20 % longer, one timeout per 1,000 queries, a memory leak and an
extra thread. It starts the whole service as `redline up` does (API server, Celery worker, one
agent; a fresh database on ``REDLINE_DATABASE_URL`` or an embedded Postgres, Redis likewise),
registers the component with the default detection settings plus ``confirm_pairs``, and reports
the revisions one by one as CI would, each once the agent is idle (so that the history is measured
in order). During the middle of the history (a third by default) a background load (one process
spinning on a core) is switched on and off at random, as another job on a shared host would.

At the end it reads the verdicts back through the API and reports:

- **false regressions per 100 unchanged revisions**: unchanged revisions with a change in a
  confirmed regression (goal ≤ 1), but for a change found late (below); ``_strict`` counts those
  too;
- **changes confirmed**: injected changes whose revision has a confirmed regression on a series
  the change targets (goals: ≥ 90 % of those of 10 % or more, the round-trip and timeout changes
  included; ≥ 60 % of the +5 % CPU changes); ``_in_range`` counts too those found late, at a
  later revision (before the next change) whose verdict was judged against a baseline older than
  the change, every revision between busy or failed;
- **agent time**: seconds the agent spent per revision on the revisions' own runs and on the
  confirmation runs (from its log), and the cost of confirmation as a share of the first (goal
  ≤ 25 %);
- what the confirmation runs decided (``--pairs``), and what the first 1 or 2 of them would have.

A CPU event's size is that of the work per pair of legs unless ``--fixed-work F`` is given:
then each raises the component's CPU per operation by its size, F being the part of that CPU no
work setting moves, in units of work, as `calibrate_cpu_events.py` measures it on this host
(measured first: "+5 %" of the work moved the CPU per operation by 0.5-5.8 %).

The suite it runs is ``objectbuilder/perf/verdicts.toml`` (the CPU case and the queryable's
round trips: about 25 s a run); one execution per revision, the default.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import random
import re
import signal
import sys
import tempfile
import threading
import time
from collections import defaultdict
from datetime import datetime
from pathlib import Path
from typing import Any

import httpx
import sqlalchemy as sa
from _service import database
from calibrate_cpu_events import calibrated_work
from make_corpus import BASE_WORK, MEMORY, Event, make_repo, plan
from measure_quiet_host import spin

ROOT = Path(__file__).resolve().parents[1]
COMPONENT = "objectbuilder"
SUITE = "objectbuilder/perf/verdicts.toml"
#: the component's CPU, and its CPU per unit of work the driver delivered, in µs and in units of
#: the host's reference work (the injected change is more work per leg pair: all move)
CPU = ("cpu_percent", "cpu_us_per_op", "cpu_refs_per_op")
RTT = ("rtt_p50_us", "rtt_p90_us")
TIMEOUTS = ("timeouts",)
EVENTS = [
    Event("cpu_plus_5", "cpu", 0.05, CPU, {"work": round(BASE_WORK * 1.05)}),
    Event("rtt_plus_20", "latency", 0.20, RTT, {"reply_delay_us": 170}),
    Event("cpu_plus_10", "cpu", 0.10, CPU, {"work": round(BASE_WORK * 1.05 * 1.10)}),
    Event("timeouts", "timeouts", 0.001, TIMEOUTS, {"drop_every": 1000}),
    Event("leak", "memory leak", 0.0, MEMORY, {"leak_kib_per_tick": 256}),
    Event("cpu_plus_30", "cpu", 0.30, CPU, {"work": round(BASE_WORK * 1.05 * 1.10 * 1.30)}),
    Event("extra_thread", "thread", 0.0, ("threads",), {"extra_threads": 1}),
    Event("cpu_plus_5b", "cpu", 0.05, CPU, {"work": round(BASE_WORK * 1.05 * 1.10 * 1.3 * 1.05)}),
]

#: what an event's code moves besides what it is meant to: the leak allocates on a thread of its
#: own, woken every 50 ms (a thread more, its mappings, 20 wake-ups a second, the allocations'
#: CPU); the extra thread maps its stack. A late find of one of these is the event's, not false.
SIDE_EFFECTS = {
    "leak": ("threads", "vms_bytes", "ctx_voluntary_per_s", *CPU),
    "extra_thread": ("vms_bytes",),
}


def calibrated(events: list[Event], fixed_work: float | None) -> list[Event]:
    """``events`` with each CPU event's work per pair raising the component's CPU per
    operation by its size (`calibrate_cpu_events`: ``fixed_work`` is the part of it no work
    setting moves, in units of work); as they are without it (the size then is the work's)."""
    if fixed_work is None:
        return events
    out, work = [], BASE_WORK
    for event in events:
        if event.kind == "cpu":
            work = calibrated_work(fixed_work, work, event.size)
            event = dataclasses.replace(event, apply={"work": work})
        out.append(event)
    return out


LARGE = 0.10  # "changes of 10 % or more": the CPU, latency and timeout ones, the leak, the thread
LOG_TIME = re.compile(r"^(\S+ \S+) agent \w+ job (\d+)(: | failed)(.*)$")


class RandomLoad:
    """One spinning process switched on and off (SIGCONT/SIGSTOP) at random, 3-30 s each way,
    while ``active`` is set."""

    def __init__(self, seed: int) -> None:
        self.process = spin()
        os.kill(self.process.pid, signal.SIGSTOP)
        self.active = threading.Event()
        self.switches = 0
        self._random = random.Random(seed)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._toggle, daemon=True)

    def _toggle(self) -> None:
        on = False
        while not self._stop.wait(self._random.uniform(3.0, 30.0)):
            want = self.active.is_set() and not on
            if want != on:
                os.kill(self.process.pid, signal.SIGCONT if want else signal.SIGSTOP)
                on, self.switches = want, self.switches + 1

    def __enter__(self) -> RandomLoad:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join()
        os.kill(self.process.pid, signal.SIGCONT)
        self.process.kill()
        self.process.wait()


def idle(engine: sa.Engine) -> bool:
    """No job waits or runs, and every revision with results has been analysed since."""
    with engine.connect() as conn:
        busy = conn.scalar(
            sa.text("SELECT count(*) FROM job WHERE state IN ('queued', 'leased', 'running')")
        )
        pending = conn.scalar(
            sa.text(
                "SELECT count(*) FROM revision r WHERE r.analyzed_at IS NULL AND EXISTS "
                "(SELECT 1 FROM execution e WHERE e.revision_id = r.id)"
            )
        )
    return not busy and not pending


def wait_idle(engine: sa.Engine, stack: Any, timeout: float = 1800.0) -> None:
    deadline = time.monotonic() + timeout
    settled = 0
    while time.monotonic() < deadline:
        stack.check_children()
        settled = settled + 1 if idle(engine) else 0
        if settled >= 3:  # idle on three looks a second apart: no pair queued meanwhile
            return
        time.sleep(1.0)
    raise TimeoutError(f"the service was not idle within {timeout:.0f} s")


def agent_seconds(log: Path) -> dict[int, float]:
    """Seconds per job id, from the agent's log line that starts it to its upload, failure or
    abandonment, the runs it repeated because the host was busy included. (Until 2026-12-05
    a repeat's warning restarted the clock: a job run three times counted as its last run, and
    the loaded part's runs, own and confirming, were counted a third of what they took.)"""
    began: dict[int, datetime] = {}
    spent: dict[int, float] = {}
    for line in log.read_text(errors="replace").splitlines():
        match = LOG_TIME.match(line)
        if match is None:
            continue
        at = datetime.strptime(match.group(1), "%Y-%m-%d %H:%M:%S,%f")
        job, rest = int(match.group(2)), match.group(3) + match.group(4)
        # a confirmation run cancelled as not needed while it ran ends in a lost lease
        if rest.startswith((": uploaded", ": lease lost", " failed")):
            if job in began:
                spent[job] = (at - began.pop(job)).total_seconds()
        elif rest.startswith(": "):
            began.setdefault(job, at)
    return spent


def targets(event: Event, series: dict[str, Any], side_effects: bool = False) -> bool:
    """Whether ``series`` is one the change is meant to move (its own, to confirm it); with
    ``side_effects``, or one its code moves as well (`SIDE_EFFECTS`: not a false regression)."""
    counter = series["counter"]
    if event.targets in (RTT, TIMEOUTS):
        return series["kind"] == "driver" and counter.split(":")[-1] in event.targets
    also = SIDE_EFFECTS.get(event.name, ()) if side_effects else ()
    return series["process"] == COMPONENT and counter in (*event.targets, *also)


def first_pairs(reason: str, effect: float, pairs: int) -> str | None:
    """What the first ``pairs`` confirmation pairs would have decided, from the figures the
    confirmation wrote ("… host: +3.1 %, -0.4 %, +5.0 %; flagged +6.0 %; a pair shows it
    beyond +4.2 %, …)"; before 2026-11-28 without the bar, which was half the flagged step);
    None without."""
    from redline.detect.confirmation import HOLD_SHARE, PAIRS_SHARE

    match = re.search(r"host: ([^;)]*); flagged", reason)
    if match is None:
        return None
    moves = [float(part.strip(" %")) / 100 for part in match.group(1).split(",")][:pairs]
    sign = -1.0 if "flagged -" in reason else 1.0
    beyond = re.search(r"shows it beyond [+-]?([0-9.]+) %", reason)
    bar = float(beyond.group(1)) / 100 if beyond else HOLD_SHARE * abs(effect)
    shown = sum(sign * move >= bar for move in moves)
    return "held" if shown >= max(1, math.ceil(PAIRS_SHARE * len(moves))) else "dropped"


def verdicts(url: str, token: str) -> list[dict[str, Any]]:
    """Every flagged detection in a regression, with its regression's confirmation."""
    headers = {"Authorization": f"Bearer {token}"}
    base = f"{url}/api/v1/components/{COMPONENT}/regressions"
    found = []
    for regression in httpx.get(base, headers=headers, timeout=60).json():
        detail = httpx.get(f"{base}/{regression['id']}", headers=headers, timeout=60).json()
        for detection in detail["flagged"]:
            found.append({**detection, "regression": regression["confirmation"]})
    return found


def flagged_anywhere(url: str, token: str) -> list[dict[str, Any]]:
    """Every verdict flagged at the end, in a regression or not, with its reason: what a change
    that ended in no regression left (a flag dropped by a later judgement, an improvement, one
    the revision's re-measured run no longer showed); the 2026-12-05 run lost CPU +30 % without
    a trace in the regressions."""
    listed: list[dict[str, Any]] = []
    params: dict[str, Any] = {"limit": 10_000}
    while True:  # every page: the list is paged (X-Next-Cursor on a full page)
        answer = httpx.get(
            f"{url}/api/v1/components/{COMPONENT}/detections",
            headers={"Authorization": f"Bearer {token}"},
            params=params,
            timeout=120,
        )
        answer.raise_for_status()
        listed += answer.json()
        if not (following := answer.headers.get("X-Next-Cursor")):
            break
        params["cursor"] = following
    return [
        {key: d[key] for key in ("revision", "method", "effect", "direction", "reason")}
        | {
            "series": d["series"]["label"],
            "confirmation": d["confirmation"],
            "confirmation_reason": d["confirmation_reason"],
            "regression_id": d["regression_id"],
        }
        for d in listed
        if d["flagged"]
    ]


def scores(
    found: list[dict[str, Any]], titles: list[str], starts: dict[int, Event], pairs: int
) -> dict[str, Any]:
    """As run, as flagged before any confirmation, and as the first 1..pairs-1 pairs would
    have decided."""
    result = {
        "as_run": score(found, titles, starts, lambda d: d["confirmation"] or "held"),
        "flagged_before_confirmation": score(found, titles, starts, lambda d: "held"),
    }
    for first_n in range(1, pairs):

        def first(detection: dict[str, Any], first_n: int = first_n) -> str:
            reason, effect = detection["confirmation_reason"], detection["effect"] or 0
            return first_pairs(reason, effect, first_n) or detection["confirmation"] or "held"

        result[f"first_{first_n}_pairs"] = score(found, titles, starts, first)
    return result


def rescore(path: Path, stretch: int, events: int) -> dict[str, Any]:
    """The figures of a run saved with --json, scored again (by this file's scoring): its
    detections' series are read back from their labels ("case/phase[params] process.counter")."""
    saved = json.loads(path.read_text())
    events_run = calibrated(EVENTS[: saved.get("events", events)], saved.get("fixed_work"))
    _, starts = plan(saved.get("stretch", stretch), events_run)
    titles = [f"r{n:03d}" for n in range(saved["revisions"])]
    found = []
    for detection in saved["detections"]:
        process, _, counter = detection["series"].split(" ", 1)[1].partition(".")
        kind = "driver" if process == "driver" else "counter"
        series = {
            "label": detection["series"],
            "process": process,
            "counter": counter,
            "kind": kind,
        }
        found.append({**detection, "series": series})
    return {**saved, **scores(found, titles, starts, saved["pairs"])}


def score(
    found: list[dict[str, Any]],
    titles: list[str],
    starts: dict[int, Event],
    state_of: Any,
) -> dict[str, Any]:
    """The goals' figures, with ``state_of(detection)`` deciding whether a detection counts as
    a confirmed regression ("held"), a dropped one, or one still suspected.

    A change is confirmed at its revision, or in range: a held detection on a series it
    targets, at a later revision, judged against a baseline older than the change (every
    revision between was busy or failed: the regression's page names them as "the change may be
    theirs"). Such a detection is the change's, found late, and not a false regression; the
    strict figures, which count it as both a miss and a false regression, are kept beside."""
    index = {title: number for number, title in enumerate(titles)}
    held: dict[int, list[dict[str, Any]]] = defaultdict(list)
    for detection in found:
        if state_of(detection) == "held":
            held[index[detection["revision"]]].append(detection)

    def covers(detection: dict[str, Any], at: int, start: int, side: bool = False) -> bool:
        baseline = index.get(detection.get("baseline") or "", at)
        return baseline < start <= at and targets(starts[start], detection["series"], side)

    unchanged = [n for n in range(len(titles)) if n not in starts]
    strict = sorted(n for n in unchanged if held.get(n))

    def late(n: int) -> bool:  # every change at n the latest change's before it, found late
        latest = max((s for s in starts if s < n), default=None)
        return latest is not None and all(covers(d, n, latest, side=True) for d in held[n])

    false = [n for n in strict if not late(n)]
    events = []
    order = sorted(starts)
    for start, event in sorted(starts.items()):
        on_target = [d for d in held.get(start, []) if targets(event, d["series"])]
        following = next((s for s in order if s > start), len(titles))  # its own change's
        in_range = sorted(
            at
            for at, listed in held.items()
            if start < at < following and any(covers(d, at, start) for d in listed)
        )
        events.append(
            {
                "event": event.name,
                "kind": event.kind,
                "size": event.size,
                "revision": start,
                "confirmed": bool(on_target),
                "confirmed_in_range_at": None if on_target or not in_range else in_range[0],
                "series": sorted({d["series"]["label"] for d in on_target}),
            }
        )

    def share(listed: list[dict[str, Any]], late: bool) -> tuple[str, float]:
        count = sum(
            e["confirmed"] or (late and e["confirmed_in_range_at"] is not None) for e in listed
        )
        return f"{count} of {len(listed)}", count / max(1, len(listed))

    large = [e for e in events if e["kind"] != "cpu" or e["size"] >= LARGE]
    small = [e for e in events if e["kind"] == "cpu" and e["size"] < LARGE]
    return {
        "unchanged_revisions": len(unchanged),
        "false_regressions": len(false),
        "false_regressions_per_100": round(100 * len(false) / max(1, len(unchanged)), 2),
        "false_regressions_strict": len(strict),
        "false_at": [
            {
                "revision": n,
                "series": sorted({d["series"]["label"] for d in held[n]}),
                "found_late": n not in false,
            }
            for n in strict
        ],
        "large_confirmed": share(large, False)[0],
        "large_confirmed_share": share(large, False)[1],
        "large_confirmed_in_range": share(large, True)[0],
        "plus5_confirmed": share(small, False)[0],
        "plus5_confirmed_share": share(small, False)[1],
        "plus5_confirmed_in_range": share(small, True)[0],
        "events": events,
    }


def run(args: argparse.Namespace, work: Path) -> dict[str, Any]:
    from redline.agent.network import free_port
    from redline.commands.stack import Stack

    knobs, starts = plan(args.stretch, calibrated(EVENTS[: args.events], args.fixed_work))
    commits = make_repo(work / "repo", knobs, starts)
    titles = [f"r{n:03d}" for n in range(len(commits))]
    middle, half = len(commits) / 2, len(commits) * args.load_share / 2
    load_from, load_to = round(middle - half), round(middle + half)
    began = time.monotonic()
    with database() as url, RandomLoad(args.seed) as load:
        os.environ["REDLINE_DATABASE_URL"] = url
        engine = sa.create_engine(url)
        stack = Stack(work / "data", free_port())
        try:
            stack.start()
            admin = {"Authorization": f"Bearer {stack.admin_token}"}
            ci = {"Authorization": f"Bearer {stack.token('ci', 'ci')}"}
            answer = httpx.post(
                f"{stack.url}/api/v1/components",
                headers=admin,
                json={"name": COMPONENT, "repo": str(work / "repo"), "suite": SUITE},
            )
            answer.raise_for_status()
            config: dict[str, Any] = {"confirm_pairs": args.pairs, "reanalyze": False}
            if args.threshold is not None:
                config["thresholds"] = {"execution_shift": {"threshold": args.threshold}}
            if args.thresholds:
                config["thresholds"] = json.loads(args.thresholds)
            answer = httpx.put(
                f"{stack.url}/api/v1/components/{COMPONENT}/detection-config",
                headers=admin,
                json=config,
            )
            answer.raise_for_status()
            for number, commit in enumerate(commits):
                (load.active.set if load_from <= number < load_to else load.active.clear)()
                answer = httpx.post(
                    f"{stack.url}/api/v1/revisions",
                    headers=ci,
                    json={
                        "component": COMPONENT,
                        "title": titles[number],
                        "sort_key": f"{number:04d}",
                        "commit": commit,
                    },
                )
                answer.raise_for_status()
                wait_idle(engine, stack)
                print(
                    f"revision {number + 1}/{len(commits)} done, {time.monotonic() - began:.0f} s",
                    file=sys.stderr,
                    flush=True,
                )
            load.active.clear()
            found = verdicts(stack.url, stack.admin_token)
            anywhere = flagged_anywhere(stack.url, stack.admin_token)
            with engine.connect() as conn:
                jobs = {
                    job: pair
                    for job, pair in conn.execute(sa.text("SELECT id, pair FROM job")).all()
                }
                # every upload's revision and recording, to judge the kept recordings again
                recordings = [
                    list(row)
                    for row in conn.execute(
                        sa.text(
                            "SELECT j.id, r.title, j.pair, e.recording_path FROM execution e "
                            "JOIN job j ON j.id = e.job_id JOIN revision r ON r.id = j.revision_id "
                            "ORDER BY j.id"
                        )
                    ).all()
                ]
        finally:
            stack.stop()
            engine.dispose()
            os.environ.pop("REDLINE_DATABASE_URL", None)
    agent_log = work / "data" / "logs" / "agent.log"
    spent = agent_seconds(agent_log)
    disturbed = agent_log.read_text(errors="replace").count("running the execution again")
    own = sum(s for job, s in spent.items() if jobs.get(job) == 0)
    confirming = sum(s for job, s in spent.items() if jobs.get(job, 0) > 0)
    result: dict[str, Any] = {
        "revisions": len(commits),
        "pairs": args.pairs,
        "execution_shift_threshold": args.threshold,
        "thresholds": json.loads(args.thresholds) if args.thresholds else None,
        "wall_seconds": round(time.monotonic() - began),
        "load_revisions": [load_from, load_to],
        "load_switches": load.switches,
        "runs_repeated_as_disturbed": disturbed,
        "agent_seconds_per_revision_own": round(own / len(commits), 1),
        "agent_seconds_per_revision_confirming": round(confirming / len(commits), 1),
        "confirmation_cost": round(confirming / own, 3) if own else None,
        "confirmation_jobs": sum(1 for pair in jobs.values() if pair > 0),
        # every job's pair (0: a revision's own run) and agent seconds, to account again
        "jobs": {str(job): [pair, spent.get(job)] for job, pair in sorted(jobs.items())},
        "stretch": args.stretch,
        "events": args.events,
        "fixed_work": args.fixed_work,
        "cpu_event_work": [e.apply["work"] for e in starts.values() if e.kind == "cpu"],
        **scores(found, titles, starts, args.pairs),
    }
    result["detections"] = [
        {
            key: detection[key]
            for key in (
                "revision",
                "baseline",
                "method",
                "effect",
                "confirmation",
                "confirmation_reason",
            )
        }
        | {"series": detection["series"]["label"], "regression": detection["regression"]}
        for detection in found
    ]
    result["flagged_anywhere"] = anywhere
    result["recordings"] = recordings
    return result


def figures(result: dict[str, Any]) -> dict[str, Any]:
    """A run's figures without its lists of detections."""
    lists = ("detections", "flagged_anywhere", "jobs", "recordings")
    return {k: v for k, v in result.items() if k not in lists}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=3, help="the component's confirm_pairs")
    parser.add_argument("--stretch", type=int, default=6, help="revisions from event to event")
    parser.add_argument(
        "--threshold", type=float, help="execution_shift's threshold (default: its own)"
    )
    parser.add_argument(
        "--thresholds",
        help="the component's thresholds as JSON, e.g. "
        '\'{"execution_shift": {"min_effect": 0.03}}\'',
    )
    parser.add_argument(
        "--load-share",
        type=float,
        default=1 / 3,
        help="the share of the history, in its middle, with the background load switched on "
        "and off at random",
    )
    parser.add_argument("--events", type=int, default=len(EVENTS), help="the first N events")
    parser.add_argument("--seed", type=int, default=1, help="of the background load's switching")
    parser.add_argument(
        "--fixed-work",
        type=float,
        help="the CPU per operation no work setting moves, in units of work (measured by "
        "calibrate_cpu_events.py): CPU events then raise the CPU per operation by their size, "
        "not the work per pair",
    )
    parser.add_argument("--json", type=Path, help="write every figure here")
    parser.add_argument(
        "--keep",
        type=Path,
        help="work in this new folder and keep it (the repository, the logs of the server, "
        "worker and agent), to find out afterwards why a change was judged as it was",
    )
    parser.add_argument(
        "--rescore", type=Path, help="score a run saved with --json again, and run nothing"
    )
    args = parser.parse_args()
    if args.rescore:
        rescored = rescore(args.rescore, args.stretch, args.events)
        args.rescore.write_text(json.dumps(rescored, indent=1) + "\n")
        print(json.dumps(figures(rescored), indent=1))
        return 0
    # a SIGTERM stops the service and the load as Ctrl-C does, rather than orphaning them
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    if args.keep:  # the service's logs (the agent's: every job's start, retries, end) stay
        args.keep.mkdir(parents=True, exist_ok=False)
        result = run(args, args.keep)
    else:
        with tempfile.TemporaryDirectory(prefix="redline-verdicts-") as folder:
            result = run(args, Path(folder))
    text = json.dumps(result, indent=1)
    if args.json:
        args.json.write_text(text + "\n")
    summary = figures(result)
    for key in ("as_run", "flagged_before_confirmation", *(f"first_{p}_pairs" for p in (1, 2))):
        if key in summary:
            summary[key] = {k: v for k, v in summary[key].items() if k != "events"}
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
