"""Corpus 2: the objectbuilder example run across a git history with injected changes.

    .venv/bin/python benchmarks/make_corpus.py [--out benchmarks/corpus/objectbuilder]

Run it on a quiet host (nothing else on the cores: on 2 cores another process moves the
component's CPU by 20-25 %); the defaults made the corpus in benchmarks/corpus/objectbuilder
(88 revisions x 5 executions, about 26 min).

Makes a git repository of ``examples/objectbuilder`` whose history has stretches of unchanged
revisions (only a comment in ``tuning.py`` differs) and, between them, one injected change of
known kind and size each: CPU +5 %, +10 %, +30 % (more work per leg pair), a memory leak, an extra
thread, extra write I/O. ``tuning.py`` carries the injection (the component imports it), so
``objectbuilder.py`` is never touched. Every revision is checked out and run ``--executions``
times (default 5) with `redline.agent.runner.run_suite` (case ``legs_and_rate``, legs 8, rate
20: 0.5 s warm-up, 2 s steady at 10 Hz). The result is written in the documented corpus format
(docs/detection.md): ``measurements.parquet`` (series, build, value, plus ``execution``) and
``labels.json``.

Series: for each event, the builds from the previous event up to (not including) the next one,
of each counter the event targets, labelled ``regression`` at the event's build; the first
stretch (before any event) gives a ``Stable`` series of every counter. Counters an event does
not target are left out of its window (a side effect, e.g. the I/O thread's CPU, is not noise).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "objectbuilder"
CASE, PHASE = "legs_and_rate", "steady"
OVERRIDES = {"legs": 8, "rate": 20}
BASE_WORK = 1000
CPU = ("cpu_percent",)
MEMORY = ("rss_bytes", "uss_bytes", "pss_bytes")
STABLE_COUNTERS = ("cpu_percent", "rss_bytes", "uss_bytes", "threads", "io_write_bytes")


@dataclass(frozen=True)
class Knobs:
    work: int = BASE_WORK
    leak_kib_per_tick: int = 0  # allocated and kept every 50 ms by a background thread
    extra_threads: int = 0  # idle threads
    io_kib_per_tick: int = 0  # written to /dev/null every 50 ms (wchar counts it)
    reply_delay_us: int = 0  # waited before each reply to objectbuilder/locate
    drop_every: int = 0  # every Nth locate query left unanswered (the caller times out)


@dataclass(frozen=True)
class Event:
    name: str
    kind: str
    size: float  # relative size of the injected change (CPU: of the work per pair)
    targets: tuple[str, ...]
    apply: dict[str, int]


EVENTS = [
    Event("cpu_plus_5", "cpu", 0.05, CPU, {"work": round(BASE_WORK * 1.05)}),
    Event("leak", "memory leak", 0.0, MEMORY, {"leak_kib_per_tick": 256}),
    Event("cpu_plus_10", "cpu", 0.10, CPU, {"work": round(BASE_WORK * 1.05 * 1.10)}),
    Event("extra_thread", "thread", 0.0, ("threads",), {"extra_threads": 1}),
    Event("cpu_plus_30", "cpu", 0.30, CPU, {"work": round(BASE_WORK * 1.05 * 1.10 * 1.30)}),
    Event("extra_io", "io", 0.0, ("io_write_bytes",), {"io_kib_per_tick": 512}),
    Event("cpu_plus_10b", "cpu", 0.10, CPU, {"work": round(BASE_WORK * 1.05 * 1.10 * 1.30 * 1.10)}),
]

TUNING = '''"""How much CPU work the objectbuilder spends per pair of legs, and injected changes.

Corpus revision {index}: {note}
"""

import threading
import time

WORK_PER_PAIR = {work}
LEAK_KIB_PER_TICK = {leak}
EXTRA_THREADS = {threads}
IO_KIB_PER_TICK = {io}
REPLY_DELAY_US = {delay}
DROP_EVERY = {drop}
_kept = []


def _background():
    block = b"x" * (IO_KIB_PER_TICK * 1024)
    with open("/dev/null", "wb") as sink:
        while True:
            if LEAK_KIB_PER_TICK:
                _kept.append(bytearray(LEAK_KIB_PER_TICK * 1024))
            if IO_KIB_PER_TICK:
                sink.write(block)
            time.sleep(0.05)


if LEAK_KIB_PER_TICK or IO_KIB_PER_TICK:
    threading.Thread(target=_background, daemon=True).start()
for _ in range(EXTRA_THREADS):
    threading.Thread(target=threading.Event().wait, daemon=True).start()
'''


def git(repo: Path, *args: str) -> str:
    env = dict(
        os.environ,
        GIT_AUTHOR_NAME="Redline Corpus",
        GIT_AUTHOR_EMAIL="c@redline.invalid",
        GIT_COMMITTER_NAME="Redline Corpus",
        GIT_COMMITTER_EMAIL="c@redline.invalid",
    )
    return subprocess.run(
        ["git", *args], cwd=repo, env=env, check=True, capture_output=True, text=True
    ).stdout.strip()


def plan(stretch: int, events: list[Event] = EVENTS) -> tuple[list[Knobs], dict[int, Event]]:
    """Knobs per revision, and which revision each event starts at."""
    knobs, starts, current = [], {}, Knobs()
    knobs += [current] * stretch
    for event in events:
        starts[len(knobs)] = event
        current = replace(current, **event.apply)
        knobs += [current] * stretch
    return knobs, starts


def make_repo(repo: Path, knobs: list[Knobs], starts: dict[int, Event]) -> list[str]:
    """One commit per revision; returns the commits in order."""
    repo.mkdir(parents=True)
    git(repo, "init", "--quiet", "--initial-branch=main")
    shutil.copytree(EXAMPLE, repo / "objectbuilder", ignore=shutil.ignore_patterns("__pycache__"))
    commits = []
    for index, knob in enumerate(knobs):
        event = starts.get(index)
        note = f"injects {event.name}" if event else "unchanged (comment only)"
        (repo / "objectbuilder" / "tuning.py").write_text(
            TUNING.format(
                index=index,
                note=note,
                work=knob.work,
                leak=knob.leak_kib_per_tick,
                threads=knob.extra_threads,
                io=knob.io_kib_per_tick,
                delay=knob.reply_delay_us,
                drop=knob.drop_every,
            )
        )
        git(repo, "add", "-A")
        git(repo, "commit", "--quiet", "-m", f"revision {index}: {note}")
        commits.append(git(repo, "rev-parse", "HEAD"))
    return commits


def run_revision(repo: Path, commit: str, out: Path, executions: int) -> list[pd.DataFrame]:
    from redline.agent.runner import RunError, run_suite
    from redline.recording import read_recording

    git(repo, "checkout", "--quiet", commit)
    frames = []
    for execution in range(executions):
        path = out / f"{commit[:10]}-{execution}.mcap"
        for attempt in (1, 2):  # a shared host can make a start time out; one retry
            try:
                run_suite(
                    repo / "objectbuilder" / "perf" / "redline.toml",
                    path,
                    only=[CASE],
                    overrides=OVERRIDES,
                )
                break
            except RunError as exc:
                print(f"{commit[:10]} execution {execution} attempt {attempt}: {exc}", flush=True)
                if attempt == 2:
                    raise
        rows = [
            (key.counter, value)
            for key, values in read_recording(path).series_samples().items()
            if key.process == "objectbuilder" and key.phase == PHASE
            for value in values
        ]
        frame = pd.DataFrame(rows, columns=["counter", "value"])
        frame["execution"] = execution
        frames.append(frame)
        path.unlink()
    return frames


def disturbed(frames: list[pd.DataFrame], expected: int = 20) -> bool:
    """An execution the shared host disturbed: its steady phase's CPU series has a sample count
    off by more than 10 % (the phase or the sampler was stretched) or a sample of zero CPU (the
    component got no message to work on: the load generator was starved)."""
    for frame in frames:
        cpu = frame.loc[frame["counter"] == "cpu_percent", "value"]
        if abs(len(cpu) - expected) > expected // 10 or bool((cpu <= 0).any()):
            return True
    return False


def build_corpus(
    samples: dict[int, list[pd.DataFrame]], starts: dict[int, Event], total: int
) -> tuple[pd.DataFrame, dict[str, dict[str, object]]]:
    """Cut the history into one window per event (and the stable start) and label it."""
    bounds = sorted(starts)
    rows, labels = [], {}

    def add(series: str, counter: str, first: int, stop: int) -> None:
        for build in range(first, stop):
            for frame in samples.get(build, []):
                part = frame[frame["counter"] == counter]
                rows.append(
                    pd.DataFrame(
                        {
                            "series": series,
                            "build": build,
                            "value": part["value"].astype(np.float64),
                            "execution": part["execution"],
                        }
                    )
                )

    for counter in STABLE_COUNTERS:
        add(f"stable/{counter}", counter, 0, bounds[0])
        labels[f"stable/{counter}"] = {"label": "Stable", "change_build": None}
    for number, start in enumerate(bounds):
        event = starts[start]
        first = bounds[number - 1] if number else 0
        stop = bounds[number + 1] if number + 1 < len(bounds) else total
        for counter in event.targets:
            series = f"{event.name}/{counter}"
            add(series, counter, first, stop)
            labels[series] = {
                "label": "regression",
                "change_build": start,
                "kind": event.kind,
                "size": event.size,
            }
    return pd.concat(rows, ignore_index=True), labels


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "corpus" / "objectbuilder"
    )
    parser.add_argument("--stretch", type=int, default=11, help="revisions between events")
    parser.add_argument("--executions", type=int, default=5)
    parser.add_argument(
        "--remeasure",
        type=int,
        default=2,
        help="measure a disturbed build again, up to this many times",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=Path(tempfile.gettempdir()) / "redline-corpus-cache",
        help="finished builds, kept for a rerun",
    )
    args = parser.parse_args()
    knobs, starts = plan(args.stretch)
    work = Path(tempfile.mkdtemp(prefix="redline-corpus-"))
    started = time.monotonic()
    try:
        commits = make_repo(work / "repo", knobs, starts)
        samples = {}
        args.cache.mkdir(parents=True, exist_ok=True)
        for build, commit in enumerate(commits):
            cached = args.cache / f"build-{build:03d}-{args.executions}.parquet"
            if cached.is_file():
                table = pd.read_parquet(cached)
                samples[build] = [part for _, part in table.groupby("execution")]
                if not (args.remeasure and disturbed(samples[build])):
                    continue
            samples[build] = run_revision(work / "repo", commit, work, args.executions)
            for _ in range(args.remeasure if disturbed(samples[build]) else 0):
                print(f"build {build}: disturbed, measured again", flush=True)
                samples[build] = run_revision(work / "repo", commit, work, args.executions)
                if not disturbed(samples[build]):
                    break
            pd.concat(samples[build]).to_parquet(cached, index=False)
            print(
                f"build {build + 1}/{len(commits)} done, {time.monotonic() - started:.0f} s",
                flush=True,
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)
    frame, labels = build_corpus(samples, starts, len(commits))
    args.out.mkdir(parents=True, exist_ok=True)
    frame.to_parquet(args.out / "measurements.parquet", index=False, compression="zstd")
    meta = {
        "name": "redline-objectbuilder-injected",
        "source": "benchmarks/make_corpus.py: examples/objectbuilder, legs_and_rate legs=8 "
        f"rate=20, {args.executions} executions per revision, {len(commits)} "
        "revisions, changes injected through tuning.py",
        "license": "same as Redline",
        "series": labels,
    }
    (args.out / "labels.json").write_text(json.dumps(meta, indent=1) + "\n")
    print(f"{len(frame)} samples, {len(labels)} series, {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
