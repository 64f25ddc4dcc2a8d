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

``--driver`` makes the corpus's driver part instead, from its own history of 33 revisions (11
unchanged, a round trip about 20 % longer through ``REPLY_DELAY_US``, 11 more, one query in
1,000 left unanswered through ``DROP_EVERY``, 11 more), each run ``--executions`` times with the
case ``locate_short`` (queries to ``objectbuilder/locate`` at 500/s for 4 s after a warm-up:
2,000 a run). It keeps the test driver's series as the reader names them (the query's round-trip
quantiles, timeouts, errors, unanswered and the queries they are counted out of; the fixed rate's
achieved rate and lateness), labelled with ``process``/``counter`` so that `redline evaluate`
judges them as the service does, and merges them into the corpus in ``--out``: the other part's
series are kept exactly as they are (checked on writing). ``--driver --probe`` only measures the
round trip of the unchanged code and of the delayed one (to size ``--reply-delay-us``).
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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

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
DRIVER_CASE, DRIVER_RATE = "locate_short", 500.0
RTT = ("rtt_p50_us", "rtt_p90_us")
TIMEOUTS = ("timeouts",)
#: about a fifth of the round trip's p50 of unchanged code on a quiet host: ``--driver --probe
#: --reply-delay-us 25`` on 2026-11-27 gave 468-483 µs unchanged, 554-563 µs with the wait
#: (time.sleep overshoots a wait this short by ~60 µs): +17.6 %. (On 2026-11-25's busy host the
#: p50 was ~880 µs and 110 µs made the fifth.)
REPLY_DELAY_US = 25


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


def driver_events(reply_delay_us: int = REPLY_DELAY_US) -> list[Event]:
    """The driver part's changes: a round trip about 20 % longer, then timeouts (1 in 1,000)."""
    return [
        Event("rtt_plus_20", "latency", 0.20, RTT, {"reply_delay_us": reply_delay_us}),
        Event("timeouts", "timeouts", 0.001, TIMEOUTS, {"drop_every": 1000}),
    ]


DRIVER_SUITE = """# Corpus 2's driver part (benchmarks/make_corpus.py --driver).
name = "objectbuilder-corpus-driver"
tests = ["test_corpus_locate.py"]
executions = 1
build = "python3 -m py_compile ../objectbuilder.py ../tuning.py"
sampling_hz = 10

[[component]]
name = "objectbuilder"
command = ["python", "../objectbuilder.py", "--threads", "2"]
ready = { log = "objectbuilder ready" }
start_timeout = 15
stop_timeout = 5
"""
DRIVER_TEST = '''"""Corpus 2's driver case: locate's queries at 500/s for 4 s, 2,000 a run."""

from redline.testing import FixedRate, Phase, TestCase
from test_locate import LOCATE

locate_short = TestCase(
    "locate_short",
    phases=[
        Phase("warmup", FixedRate(200, 0.5, LOCATE), warmup=True),
        Phase("steady", FixedRate(500, 4.0, LOCATE)),
    ],
)
'''
DRIVER_FILES = {"corpus_driver.toml": DRIVER_SUITE, "test_corpus_locate.py": DRIVER_TEST}

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


def write_tuning(tree: Path, index: int, note: str, knob: Knobs) -> None:
    """The example's ``tuning.py`` in ``tree`` set to ``knob`` (revision ``index``: ``note``)."""
    (tree / "tuning.py").write_text(
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


def make_repo(
    repo: Path, knobs: list[Knobs], starts: dict[int, Event], perf: dict[str, str] | None = None
) -> list[str]:
    """One commit per revision; returns the commits in order. ``perf``: more files for the
    example's ``perf`` folder (name: text), in every revision."""
    repo.mkdir(parents=True)
    git(repo, "init", "--quiet", "--initial-branch=main")
    shutil.copytree(EXAMPLE, repo / "objectbuilder", ignore=shutil.ignore_patterns("__pycache__"))
    for name, text in (perf or {}).items():
        (repo / "objectbuilder" / "perf" / name).write_text(text)
    commits = []
    for index, knob in enumerate(knobs):
        event = starts.get(index)
        note = f"injects {event.name}" if event else "unchanged (comment only)"
        write_tuning(repo / "objectbuilder", index, note, knob)
        git(repo, "add", "-A")
        git(repo, "commit", "--quiet", "-m", f"revision {index}: {note}")
        commits.append(git(repo, "rev-parse", "HEAD"))
    return commits


Keep = Callable[[Any], str | None]
Windows = Callable[[Event], Sequence[str]]


def component_counter(key: Any) -> str | None:
    """The component's counters of the CPU case's steady phase (the counters part)."""
    return key.counter if key.process == "objectbuilder" and key.phase == PHASE else None


def driver_counter(key: Any) -> str | None:
    """The driver's metrics of the query case's steady phase, and what else used the host."""
    from redline.recording import HOST_PROCESS
    from redline.recording.disturbance import OTHER_CPU
    from redline.recording.driver import DRIVER_PROCESS

    if (key.case, key.phase) != (DRIVER_CASE, PHASE):
        return None
    if key.process == DRIVER_PROCESS or (key.process, key.counter) == (HOST_PROCESS, OTHER_CPU):
        return key.counter
    return None


def run_revision(
    repo: Path,
    commit: str,
    out: Path,
    executions: int,
    suite: str = "redline.toml",
    case: str = CASE,
    keep: Keep = component_counter,
) -> list[pd.DataFrame]:
    from redline.agent.runner import RunError, run_suite
    from redline.recording import read_recording

    git(repo, "checkout", "--quiet", commit)
    frames = []
    for execution in range(executions):
        path = out / f"{commit[:10]}-{execution}.mcap"
        for attempt in (1, 2):  # a shared host can make a start time out; one retry
            try:
                run_suite(
                    repo / "objectbuilder" / "perf" / suite,
                    path,
                    only=[case],
                    overrides=OVERRIDES if case == CASE else None,
                )
                break
            except RunError as exc:
                print(f"{commit[:10]} execution {execution} attempt {attempt}: {exc}", flush=True)
                if attempt == 2:
                    raise
        rows = [
            (counter, value)
            for key, values in read_recording(path).series_samples().items()
            if (counter := keep(key)) is not None
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


def driver_disturbed(frames: list[pd.DataFrame]) -> bool:
    """An execution of the query case the host disturbed: other load over the service's
    threshold (`redline.recording.disturbance`), or the driver short of its rate by 2 %."""
    from redline.recording.disturbance import DEFAULT_THRESHOLD, OTHER_CPU

    for frame in frames:
        other = frame.loc[frame["counter"] == OTHER_CPU, "value"]
        rate = frame.loc[frame["counter"].str.endswith(":rate_achieved"), "value"]
        if bool((other > DEFAULT_THRESHOLD).any()) or rate.empty:
            return True
        if bool((rate < 0.98 * DRIVER_RATE).any()):
            return True
    return False


def with_totals(chosen: Sequence[str], every: Sequence[str]) -> list[str]:
    """``chosen`` and what its counts of rare events are counted out of (the first of the
    metric's ``of`` fields the runs reported, as the worker finds it)."""
    from redline.recording.driver import metric_of

    out = list(chosen)
    for counter in chosen:
        metric, stem = metric_of(counter), counter.rpartition(":")[0]
        named = [f"{stem}:{of}" for of in (metric.of if metric else ()) if f"{stem}:{of}" in every]
        if named and named[0] not in out:
            out.append(named[0])
    return out


def driver_windows(samples: dict[int, list[pd.DataFrame]]) -> tuple[list[str], Windows]:
    """The driver part's stable counters (every judged metric) and each event's (its target
    fields), each with the totals of its counts."""
    from redline.detect.counters import judged
    from redline.recording.driver import DRIVER_PROCESS

    every = sorted(
        {c for frames in samples.values() for f in frames for c in f["counter"] if ":" in c}
    )
    stable = with_totals([c for c in every if judged(DRIVER_PROCESS, c)], every)

    def window(event: Event) -> list[str]:
        return with_totals([c for c in every if c.rpartition(":")[2] in event.targets], every)

    return stable, window


def driver_label(counter: str) -> dict[str, object]:
    """What `redline evaluate` needs to judge a driver series as the service does; a load (the
    queries sent) is labelled ``load``: it is what counts are counted out of, not judged."""
    from redline.recording.driver import DRIVER_PROCESS, metric_of

    about: dict[str, object] = {"process": DRIVER_PROCESS, "counter": counter}
    return about if metric_of(counter) else {"label": "load", "change_build": None, **about}


def build_corpus(
    samples: dict[int, list[pd.DataFrame]],
    starts: dict[int, Event],
    total: int,
    stable: Sequence[str] = STABLE_COUNTERS,
    window: Windows = lambda event: event.targets,
    about: Callable[[str], dict[str, object]] = lambda counter: {},
) -> tuple[pd.DataFrame, dict[str, dict[str, object]]]:
    """Cut the history into one window per event (and the stable start) and label it:
    ``stable`` the counters of the stable start, ``window`` an event's, ``about`` what more a
    counter's label says (for the driver's: `driver_label`)."""
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

    for counter in stable:
        add(f"stable/{counter}", counter, 0, bounds[0])
        labels[f"stable/{counter}"] = {"label": "Stable", "change_build": None, **about(counter)}
    for number, start in enumerate(bounds):
        event = starts[start]
        first = bounds[number - 1] if number else 0
        stop = bounds[number + 1] if number + 1 < len(bounds) else total
        for counter in window(event):
            series = f"{event.name}/{counter}"
            add(series, counter, first, stop)
            entry = {"label": "regression", "change_build": start, **about(counter)}
            labels[series] = (
                entry
                if entry["label"] == "load"
                else {
                    **entry,
                    "kind": event.kind,
                    "size": event.size,
                }
            )
    return pd.concat(rows, ignore_index=True), labels


def part_of(entry: dict[str, Any]) -> str:
    """Which part of the corpus a series belongs to: ``driver`` or ``counters``."""
    return "driver" if entry.get("process") == "driver" else "counters"


def merge(out: Path, part: str, frame: pd.DataFrame, labels: dict[str, Any], source: str) -> None:
    """Write one part's series into the corpus in ``out``, the other part's kept as they are:
    its rows are read back and compared (values, builds, executions, order) before returning."""
    path, meta_path = out / "measurements.parquet", out / "labels.json"
    old = pd.read_parquet(path) if path.is_file() else frame.iloc[:0]
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    parts = meta.get("parts") or ({"counters": meta["source"]} if meta.get("source") else {})
    parts[part] = source
    others = {s: e for s, e in meta.get("series", {}).items() if part_of(e) != part}
    kept = old[old["series"].isin(others)].reset_index(drop=True)
    merged = pd.concat([kept, frame[kept.columns]], ignore_index=True)
    out.mkdir(parents=True, exist_ok=True)
    merged.to_parquet(path, index=False, compression="zstd")
    meta = {
        "name": "redline-objectbuilder-injected",
        "source": "; ".join(f"{name} part: {text}" for name, text in parts.items()),
        "license": "same as Redline",
        "parts": parts,
        "series": {**others, **labels},
    }
    meta_path.write_text(json.dumps(meta, indent=1) + "\n")
    again = pd.read_parquet(path)
    if not again[again["series"].isin(others)].reset_index(drop=True).equals(kept):
        raise RuntimeError(f"{path}: the series of the other part changed on writing")


Run = Callable[[Path, str, Path, int], list[pd.DataFrame]]


def measure(
    repo: Path,
    commits: list[str],
    args: argparse.Namespace,
    run: Run,
    is_disturbed: Callable[[list[pd.DataFrame]], bool],
    cache: str,
) -> dict[int, list[pd.DataFrame]]:
    """Every revision's executions, each revision cached as ``cache``.format(build=...) once
    measured; a disturbed one measured again (up to ``--remeasure`` times)."""
    samples, started = {}, time.monotonic()
    args.cache.mkdir(parents=True, exist_ok=True)
    for build, commit in enumerate(commits):
        cached = args.cache / cache.format(build=build)
        if cached.is_file():
            table = pd.read_parquet(cached)
            samples[build] = [part for _, part in table.groupby("execution")]
            if not (args.remeasure and is_disturbed(samples[build])):
                continue
        samples[build] = run(repo, commit, repo.parent, args.executions)
        for _ in range(args.remeasure if is_disturbed(samples[build]) else 0):
            print(f"build {build}: disturbed, measured again", flush=True)
            samples[build] = run(repo, commit, repo.parent, args.executions)
            if not is_disturbed(samples[build]):
                break
        pd.concat(samples[build]).to_parquet(cached, index=False)
        print(
            f"build {build + 1}/{len(commits)} done, {time.monotonic() - started:.0f} s",
            flush=True,
        )
    return samples


def run_driver(repo: Path, commit: str, out: Path, executions: int) -> list[pd.DataFrame]:
    return run_revision(
        repo, commit, out, executions, "corpus_driver.toml", DRIVER_CASE, driver_counter
    )


def probe(repo: Path, commits: list[str], stretch: int, delay: int) -> None:
    """The round trip of the unchanged code and of the first delayed revision, 3 runs each."""
    for name, commit in (("unchanged", commits[0]), (f"REPLY_DELAY_US={delay}", commits[stretch])):
        frames = run_driver(repo, commit, repo.parent, 3)
        for field in RTT:
            values = [
                float(f.loc[f["counter"].str.endswith(f":{field}"), "value"].iloc[0])
                for f in frames
            ]
            print(f"{name}: {field} {', '.join(f'{v:.0f}' for v in values)} us", flush=True)


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
    parser.add_argument(
        "--driver",
        action="store_true",
        help="make the driver part (its own history) and merge it into --out",
    )
    parser.add_argument(
        "--reply-delay-us",
        type=int,
        default=REPLY_DELAY_US,
        help="the round trip's injected wait (about 20 %% of its p50)",
    )
    parser.add_argument(
        "--probe",
        action="store_true",
        help="with --driver: only print the round trip without and with the wait",
    )
    args = parser.parse_args()
    events = driver_events(args.reply_delay_us) if args.driver else EVENTS
    knobs, starts = plan(args.stretch, events)
    work = Path(tempfile.mkdtemp(prefix="redline-corpus-"))
    started = time.monotonic()
    try:
        repo = work / "repo"
        commits = make_repo(repo, knobs, starts, DRIVER_FILES if args.driver else None)
        if args.driver and args.probe:
            probe(repo, commits, args.stretch, args.reply_delay_us)
            return 0
        if args.driver:
            cache = f"driver-{{build:03d}}-{args.executions}-{args.reply_delay_us}.parquet"
            samples = measure(repo, commits, args, run_driver, driver_disturbed, cache)
        else:
            cache = f"build-{{build:03d}}-{args.executions}.parquet"
            samples = measure(repo, commits, args, run_revision, disturbed, cache)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if args.driver:
        stable, window = driver_windows(samples)
        frame, labels = build_corpus(samples, starts, len(commits), stable, window, driver_label)
        source = (
            f"benchmarks/make_corpus.py --driver: examples/objectbuilder, {DRIVER_CASE} (500 "
            f"queries/s for 4 s), {args.executions} executions per revision, {len(commits)} "
            f"revisions of their own, REPLY_DELAY_US={args.reply_delay_us} then DROP_EVERY=1000 "
            "injected through tuning.py"
        )
    else:
        frame, labels = build_corpus(samples, starts, len(commits))
        source = (
            "benchmarks/make_corpus.py: examples/objectbuilder, legs_and_rate legs=8 "
            f"rate=20, {args.executions} executions per revision, {len(commits)} "
            "revisions, changes injected through tuning.py"
        )
    merge(args.out, "driver" if args.driver else "counters", frame, labels, source)
    print(f"{len(frame)} samples, {len(labels)} series, {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
