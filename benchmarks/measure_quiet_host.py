"""Is the host quiet, and does pinning help? The measurements behind issue 11's two defaults.

Runs `redline calibrate` on the objectbuilder example in four conditions, each EXECUTIONS
executions of the same code: without and with CPU affinity (the component on core 1, Redline's
driver, recorder and monitor on core 0), on a quiet host and with a background load (one
process spinning on the CPU, as another job on the host would). A fifth run switches that load
on and off while the suite runs (on ON_S seconds, off OFF_S, logged with wall-clock times), so
each measured phase was loaded for a known share of its time.

It reports, per condition: the spread between executions (median and largest coefficient of
variation over the component's judged series, and of its steady-phase `cpu_percent`), and the
other load measured per phase (`other_cpu_percent`: what the run's own processes did not use);
for the switched run, each phase's loaded share beside its other load and whether the
disturbed-phase detector (at the threshold in force) flagged it. DEFAULT_THRESHOLD and the
affinity default are chosen from these figures (docs/detection.md).

Run on an otherwise idle host: .venv/bin/python benchmarks/measure_quiet_host.py [EXECUTIONS]
Writes its figures as JSON beside the printout (benchmarks/results/quiet_host.json).
"""

from __future__ import annotations

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
from redline.recording.disturbance import OTHER_CPU, threshold
from redline.recording.format import HOST_PROCESS, canonical_params

ROOT = Path(__file__).resolve().parents[1]
SUITE = ROOT / "examples" / "objectbuilder" / "perf" / "redline.toml"
COMPONENT = "objectbuilder"
PINNED = "\n[affinity]\ncomponents = [1]\ndriver = [0]\nrecorder = [0]\nmonitor = [0]\n"
ON_S, OFF_S = 4.0, 6.0


def spin() -> subprocess.Popen[bytes]:
    """Another job on the host: one process keeping one core busy."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


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


def calibrate(suite: Path, executions: int, folder: Path) -> dict[str, Any]:
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


def spread(result: dict[str, Any]) -> dict[str, float]:
    own = [s for s in result["series"] if f" {COMPONENT}." in s["series"] and s["cv"] is not None]
    cvs = [s["cv"] for s in own]
    cpu = [s["cv"] for s in own if s["series"].endswith(f" {COMPONENT}.cpu_percent")]
    return {
        "series": len(cvs),
        "median_cv": statistics.median(cvs) if cvs else float("nan"),
        "max_cv": max(cvs) if cvs else float("nan"),
        "cpu_percent_median_cv": statistics.median(cpu) if cpu else float("nan"),
        "cpu_percent_max_cv": max(cpu) if cpu else float("nan"),
    }


def main() -> None:
    executions = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    limit = threshold()
    report: dict[str, Any] = {"executions": executions, "threshold": limit, "conditions": {}}
    with tempfile.TemporaryDirectory(prefix="redline-quiet-") as tmp:
        pinned = SUITE.with_name(".measure-pinned.toml")
        pinned.write_text(SUITE.read_text() + PINNED)
        try:
            for name, suite in (("unpinned", SUITE), ("pinned", pinned)):
                for load in ("quiet", "loaded"):
                    folder = Path(tmp) / f"{name}-{load}"
                    hog = spin() if load == "loaded" else None
                    try:
                        result = calibrate(suite, executions, folder)
                    finally:
                        if hog is not None:
                            hog.kill()
                            hog.wait()
                    others = [p["other_cpu"] for p in result["phases"]]
                    report["conditions"][f"{name} {load}"] = {
                        **spread(result),
                        "other_cpu": sorted(round(o, 1) for o in others),
                        "flagged": sum(o > limit for o in others),
                        "phases": len(others),
                    }
                    print(
                        f"{name:>9} {load:<7}", json.dumps(report["conditions"][f"{name} {load}"])
                    )
            folder = Path(tmp) / "switched"
            with Switched() as load:
                result = calibrate(SUITE, executions, folder)
            rows = []
            for p in result["phases"]:
                share = load.share(p["begin_ns"], p["end_ns"])
                rows.append(
                    {
                        "loaded_share": round(share, 2),
                        "other_cpu": round(p["other_cpu"], 1),
                        "flagged": p["other_cpu"] > limit,
                    }
                )
            report["switched"] = sorted(rows, key=lambda r: r["loaded_share"])
            for row in report["switched"]:
                print("switched", json.dumps(row))
        finally:
            pinned.unlink(missing_ok=True)
    results = ROOT / "benchmarks" / "results"
    results.mkdir(exist_ok=True)
    (results / "quiet_host.json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
