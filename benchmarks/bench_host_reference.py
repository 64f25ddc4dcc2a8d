"""How much of one execution's CPU noise the host-speed reference takes out.

    .venv/bin/python benchmarks/bench_host_reference.py [-n 8] [--suite SUITE.toml]
    .venv/bin/python benchmarks/bench_host_reference.py --recordings DIR

Runs `redline calibrate` on the same code N times (by default the objectbuilder's
``verdicts.toml``: its CPU case at four parameter sets and its queryable), or reads the
recordings of such a run, and prints per test case, phase and parameter set the spread between
executions of the component's CPU per unit of work as measured (``cpu_us_per_op``) and in units
of the host's reference work timed beside it (``cpu_refs_per_op``, the judged one): the
coefficient of variation and the robust sd (1.4826 times the median absolute deviation, over
the median), and the second's ratio to the first (below 1: the reference took noise out). Also
the correlation of the reference's mean with the CPU per operation. Run on an otherwise idle
host; docs/detection.md has the figures ("The host-speed reference").
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from redline.recording import read_recording
from redline.recording.driver import CPU_PER_OP, CPU_REFS_PER_OP, HOST_REFERENCE
from redline.recording.format import HOST_PROCESS, params_name

ROOT = Path(__file__).resolve().parents[1]
SUITE = ROOT / "examples" / "objectbuilder" / "perf" / "verdicts.toml"
COMPONENT = "objectbuilder"
REDLINE = str(Path(sys.executable).parent / "redline")


def spreads(values: list[float]) -> tuple[float, float]:
    """The CV and the robust sd of one series' execution values, in % of their mean/median."""
    array = np.asarray(values, dtype=float)
    median = float(np.median(array))
    robust = 1.4826 * float(np.median(np.abs(array - median))) / median
    return 100 * float(np.std(array, ddof=1) / np.mean(array)), 100 * robust


def execution_values(folder: Path) -> dict[str, dict[str, list[float]]]:
    """Per segment (``case/phase[params]``): each execution's CPU per operation in µs and in
    references, and the reference's mean over the segment."""
    found: dict[str, dict[str, list[float]]] = {}
    for path in sorted(folder.glob("*.mcap")):
        samples = read_recording(path).series_samples()
        for key, in_refs in samples.items():
            if key.process != COMPONENT or key.counter != CPU_REFS_PER_OP:
                continue
            in_us = samples[dataclasses.replace(key, counter=CPU_PER_OP)]
            timings = samples[
                dataclasses.replace(key, process=HOST_PROCESS, counter=HOST_REFERENCE)
            ]
            name = f"{key.case}/{key.phase}[{params_name(json.loads(key.params))}]"
            row = found.setdefault(name, {CPU_PER_OP: [], CPU_REFS_PER_OP: [], HOST_REFERENCE: []})
            row[CPU_PER_OP].append(float(np.mean(in_us)))
            row[CPU_REFS_PER_OP].append(float(np.mean(in_refs)))
            row[HOST_REFERENCE].append(float(np.mean(timings)))
    return found


def report(found: dict[str, dict[str, list[float]]]) -> None:
    print(
        f"{'segment':36} {'n':>2} {'us: cv / rsd':>14} {'refs: cv / rsd':>15}"
        f" {'ratio':>11} {'r':>5}"
    )
    for name, row in sorted(found.items()):
        if len(row[CPU_PER_OP]) < 3:
            continue
        us, refs = spreads(row[CPU_PER_OP]), spreads(row[CPU_REFS_PER_OP])
        correlation = float(np.corrcoef(row[CPU_PER_OP], row[HOST_REFERENCE])[0, 1])
        print(
            f"{name:36} {len(row[CPU_PER_OP]):2d} {us[0]:6.1f} / {us[1]:4.1f} %"
            f" {refs[0]:6.1f} / {refs[1]:4.1f} % {refs[0] / us[0]:5.2f}/{refs[1] / us[1]:4.2f}"
            f" {correlation:5.2f}"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-n", "--executions", type=int, default=8)
    parser.add_argument("--suite", type=Path, default=SUITE)
    parser.add_argument("--recordings", type=Path, help="read these recordings; run nothing")
    args = parser.parse_args()
    if args.recordings:
        report(execution_values(args.recordings))
        return 0
    with tempfile.TemporaryDirectory(prefix="redline-reference-") as folder:
        subprocess.run(
            [REDLINE, "calibrate", str(args.suite), "-n", str(args.executions), "--out", folder],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        report(execution_values(Path(folder)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
