"""Is the host quiet, and does pinning help? The measurements behind issue 11's two defaults.

Runs `redline calibrate` on the objectbuilder example in four conditions, each EXECUTIONS
executions of the same code: without and with CPU affinity (the component on core 1, Redline's
driver, recorder and monitor on core 0), on a quiet host and with a background load (one
process spinning on the CPU, as another job on the host would). A fifth run switches that load
on and off while the suite runs (on ON_S seconds, off OFF_S, logged with wall-clock times), so
each measured phase was loaded for a known share of its time.

It reports, per condition: the spread between executions (median and largest coefficient of
variation over the component's judged series, of its `cpu_percent`, of its CPU per unit of work
`cpu_us_per_op`, and of the test driver's round trips where the suite queries), and the other
load measured per phase (`other_cpu_percent`: what the run's own processes did not use). In the
loaded conditions the disturbed-phase check is switched off for `calibrate` (it would leave every
phase out), so their spread is what a busy host does to the figures; each phase is still counted
as flagged or not at the threshold in force;
for the switched run, each phase's loaded share beside its other load and whether the
disturbed-phase detector (at the threshold in force) flagged it. DEFAULT_THRESHOLD and the
affinity default are chosen from these figures (docs/detection.md).

Run on an otherwise idle host:

    .venv/bin/python benchmarks/measure_quiet_host.py [EXECUTIONS] [--suite SUITE.toml]

(default the example's redline.toml; its verdicts.toml adds 500 queries/s, so the round trips'
spread too). Writes its figures as JSON beside the printout (benchmarks/results/quiet_host.json,
or quiet_host-SUITE.json for another suite).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from redline.recording import read_recording
from redline.recording.disturbance import OTHER_CPU, THRESHOLD_VARIABLE, threshold
from redline.recording.format import HOST_PROCESS, canonical_params

ROOT = Path(__file__).resolve().parents[1]
SUITE = ROOT / "examples" / "objectbuilder" / "perf" / "redline.toml"
COMPONENT = "objectbuilder"
PINNED = "\n[affinity]\ncomponents = [1]\ndriver = [0]\nrecorder = [0]\nmonitor = [0]\n"
ON_S, OFF_S = 4.0, 6.0


def spin() -> subprocess.Popen[bytes]:
    """Another job on the host: one process keeping one core busy.

    In a session of its own: in the benchmark's process group, the kernel continues it
    (SIGHUP, then SIGCONT) whenever that group is orphaned with it stopped, which happens when
    the benchmark was started in the background from a shell that then exits, and the load the
    benchmarks switch off with SIGSTOP then runs throughout."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)


class Switched:
    """The load switched on and off (SIGCONT/SIGSTOP), each switch logged in wall-clock ns."""

    def __init__(self) -> None:
        self.process = spin()
        self.on: list[tuple[int, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._toggle, daemon=True)

    def _toggle(self) -> None:
        while not self._stop.is_set():
            began = time.time_ns()
            os.kill(self.process.pid, signal.SIGCONT)
            self._stop.wait(ON_S)
            os.kill(self.process.pid, signal.SIGSTOP)
            self.on.append((began, time.time_ns()))
            self._stop.wait(OFF_S)

    def __enter__(self) -> Switched:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join()
        os.kill(self.process.pid, signal.SIGCONT)
        self.process.kill()
        self.process.wait()

    def share(self, begin: int, end: int) -> float:
        """The share of [begin, end] the load was on."""
        on = sum(max(0, min(end, b) - max(begin, a)) for a, b in self.on)
        return on / max(1, end - begin)


def calibrate(suite: Path, executions: int, folder: Path, check: bool) -> dict[str, Any]:
    """`redline calibrate`'s figures and each phase's other load; ``check`` off lets every phase
    count however busy the host was (the spread a busy host gives)."""
    out = folder / "recordings"
    figures = folder / "calibrate.json"
    subprocess.run(
        [
            str(Path(sys.executable).with_name("redline")),
            "calibrate",
            str(suite),
            "-n",
            str(executions),
            "--out",
            str(out),
            "--json",
            str(figures),
        ],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=dict(os.environ) if check else {**os.environ, THRESHOLD_VARIABLE: "1e9"},
    )
    result = json.loads(figures.read_text())
    result["phases"] = phases(sorted(out.glob("*.mcap")))
    return result


def phases(recordings: list[Path]) -> list[dict[str, Any]]:
    """Each measured phase of each recording: its time span and the other load measured."""
    rows = []
    for path in recordings:
        recording = read_recording(path)
        spans = {
            (s.case, s.phase, canonical_params(s.params)): (s.begin_ns, s.end_ns)
            for s in recording.segments()
            if not s.warmup
        }
        for key, values in recording.series_samples().items():
            if key.process == HOST_PROCESS and key.counter == OTHER_CPU and values:
                begin, end = spans.get((key.case, key.phase, key.params), (0, 0))
                rows.append(
                    {
                        "recording": path.name,
                        "segment": key.label(),
                        "begin_ns": begin,
                        "end_ns": end,
                        "other_cpu": statistics.fmean(values),
                    }
                )
    return rows


#: the series whose spread is reported apart, by how their label ends
APART = {
    "cpu_percent": f" {COMPONENT}.cpu_percent",
    "cpu_us_per_op": f" {COMPONENT}.cpu_us_per_op",
    "rtt_p50_us": ":rtt_p50_us",
    "rtt_p90_us": ":rtt_p90_us",
}


def _cvs(cvs: list[float]) -> dict[str, Any]:
    if not cvs:
        return {"n": 0, "median_cv": None, "max_cv": None}
    return {"n": len(cvs), "median_cv": statistics.median(cvs), "max_cv": max(cvs)}


def spread(result: dict[str, Any]) -> dict[str, Any]:
    """The coefficients of variation between executions: over the component's judged series,
    and of each series kind in `APART` (the driver's included)."""
    rows = [s for s in result["series"] if s["cv"] is not None]
    own = [s["cv"] for s in rows if f" {COMPONENT}." in s["series"]]
    figures = {"component": _cvs(own)}
    for name, ending in APART.items():
        figures[name] = _cvs([s["cv"] for s in rows if s["series"].endswith(ending)])
    return figures


def condition(suite: Path, load: str, executions: int, folder: Path, limit: float) -> dict:
    """One condition's spread and other load: ``load`` "quiet", or "loaded" (one core spun)."""
    hog = spin() if load == "loaded" else None
    try:
        result = calibrate(suite, executions, folder, check=hog is None)
    finally:
        if hog is not None:
            hog.kill()
            hog.wait()
    others = [p["other_cpu"] for p in result["phases"]]
    return {
        **spread(result),
        "other_cpu": sorted(round(o, 1) for o in others),
        "flagged": sum(o > limit for o in others),
        "phases": len(others),
    }


def switched(suite: Path, executions: int, folder: Path, limit: float) -> list[dict[str, Any]]:
    """Each phase's loaded share beside its other load and whether it was flagged."""
    with Switched() as load:
        result = calibrate(suite, executions, folder, check=True)
    rows = [
        {
            "loaded_share": round(load.share(p["begin_ns"], p["end_ns"]), 2),
            "other_cpu": round(p["other_cpu"], 1),
            "flagged": p["other_cpu"] > limit,
        }
        for p in result["phases"]
    ]
    return sorted(rows, key=lambda r: r["loaded_share"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("executions", nargs="?", type=int, default=5)
    parser.add_argument("--suite", type=Path, default=SUITE)
    parser.add_argument(
        "--rounds",
        type=int,
        default=0,
        help="only the quiet host, without and with affinity alternately, this many times each "
        "(one run's spread of 5 executions is itself noisy)",
    )
    args = parser.parse_args()
    executions, suite_file = args.executions, args.suite.resolve()
    limit = threshold()
    report: dict[str, Any] = {
        "executions": executions,
        "threshold": limit,
        "suite": str(suite_file.relative_to(ROOT)),
        "measured": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "load_1min_before": os.getloadavg()[0],
    }
    with tempfile.TemporaryDirectory(prefix="redline-quiet-") as tmp:
        pinned = suite_file.with_name(".measure-pinned.toml")
        pinned.write_text(suite_file.read_text() + PINNED)
        suites = {"unpinned": suite_file, "pinned": pinned}
        try:
            if args.rounds:
                report["rounds"] = []
                for index in range(args.rounds):
                    order = list(suites) if index % 2 == 0 else list(reversed(suites))
                    row = {}
                    for name in order:
                        folder = Path(tmp) / f"{name}-{index}"
                        row[name] = condition(suites[name], "quiet", executions, folder, limit)
                        print(f"round {index} {name:>9}", json.dumps(row[name]), flush=True)
                    report["rounds"].append(row)
            else:
                report["conditions"] = {}
                for name, suite in suites.items():
                    for load in ("quiet", "loaded"):
                        folder = Path(tmp) / f"{name}-{load}"
                        found = condition(suite, load, executions, folder, limit)
                        report["conditions"][f"{name} {load}"] = found
                        print(f"{name:>9} {load:<7}", json.dumps(found), flush=True)
                report["switched"] = switched(suite_file, executions, Path(tmp) / "sw", limit)
                for row in report["switched"]:
                    print("switched", json.dumps(row))
        finally:
            pinned.unlink(missing_ok=True)
    results = ROOT / "benchmarks" / "results"
    results.mkdir(exist_ok=True)
    name = "quiet_host" if suite_file == SUITE else f"quiet_host-{suite_file.stem}"
    name += "-rounds" if args.rounds else ""
    (results / f"{name}.json").write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
