"""How much more work per leg pair makes the objectbuilder's CPU per operation rise by a given
share: the calibration of `bench_verdicts`'s CPU events.

    .venv/bin/python benchmarks/calibrate_cpu_events.py [--runs 3] [--json FILE]

`bench_verdicts` injected "CPU +5 %" as 5 % more work per pair of legs (``WORK_PER_PAIR``), but
the component's CPU per operation has a part no work setting moves (zenoh, decoding, Python's
own): it rose 0.5-5.8 % for "+5 %". This runs the suite `bench_verdicts` runs
(``objectbuilder/perf/verdicts.toml``) at several work settings (half, once, one and a half and
twice `BASE_WORK`), ``--runs`` times each, on a copy of the example, and fits the component's
CPU per operation (the median of each run's samples, per parameter set of the CPU case) as
``a + b * work``. Then the work that raises the CPU per operation by ``p`` from a setting ``W``
is ``W + p * (a / b + W)`` (`calibrated_work`); ``a / b`` is the fixed part in units of work,
which `bench_verdicts --fixed-work` takes: that of the series carrying most of the component's
CPU (``fixed_work_heaviest``). Run on a quiet host: the fit's residuals are
what the host's noise leaves.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from statistics import median
from typing import Any

import numpy as np
from make_corpus import BASE_WORK, EXAMPLE, Knobs, write_tuning

REDLINE = str(Path(sys.executable).parent / "redline")
SUITE = "perf/verdicts.toml"
#: near the events' own settings (1 to 1.5 times `BASE_WORK`), where the line is to hold
SETTINGS = (BASE_WORK // 2, BASE_WORK, 3 * BASE_WORK // 2, 2 * BASE_WORK)
COMPONENT = "objectbuilder"
PER_OP = "cpu_us_per_op"


def cpu_per_op(recording: Path) -> dict[str, float]:
    """The component's CPU per operation in one recording: its samples' median, per test case,
    phase and parameter set."""
    from redline.recording import read_recording

    found = {}
    for key, series in read_recording(recording).series_samples().items():
        if key.process == COMPONENT and key.counter == PER_OP and len(series):
            found[key.label()] = float(np.median(np.asarray(series, dtype=float)))
    return found


def measure(work: int, runs: int, tree: Path) -> list[dict[str, float]]:
    write_tuning(tree, 0, f"calibration at {work}", Knobs(work=work))
    found = []
    for run in range(runs):
        out = tree / f"w{work}-{run}.mcap"
        done = subprocess.run(
            [REDLINE, "run", SUITE, "--out", str(out)], cwd=tree, capture_output=True, text=True
        )
        if done.returncode != 0:
            raise SystemExit(f"redline run at work {work} failed:\n{done.stderr[-2000:]}")
        found.append(cpu_per_op(out))
        print(f"work {work} run {run + 1}: {found[-1]}", file=sys.stderr, flush=True)
    return found


def fit(by_work: dict[int, list[dict[str, float]]]) -> dict[str, Any]:
    """Per series, ``a`` and ``b`` of CPU per op = a + b * work over every run, with the
    fixed part in units of work (``a / b``) and the fit's relative residual."""
    series = sorted({label for runs in by_work.values() for run in runs for label in run})
    fits = {}
    for label in series:
        points = [
            (work, run[label]) for work, runs in by_work.items() for run in runs if label in run
        ]
        x, y = np.array([p[0] for p in points], float), np.array([p[1] for p in points], float)
        b, a = np.polyfit(x, y, 1)
        residual = float(np.sqrt(np.mean((y - (a + b * x)) ** 2)) / np.mean(y))
        fits[label] = {
            "a_us": round(float(a), 2),
            "b_us_per_work": round(float(b), 5),
            "fixed_work": round(float(a / b), 1) if b > 0 else None,
            "relative_residual": round(residual, 4),
            "medians_us": {work: round(median(y[x == work]), 2) for work in by_work},
        }
    return fits


def summary(fits: dict[str, Any]) -> dict[str, Any]:
    """The fixed part of the series that carries most of the component's CPU (the largest CPU
    per operation at `BASE_WORK`: what "the component's CPU" means for an event), and the
    median over all series (the light ones' fixed part is most of their CPU)."""
    heaviest = max(fits, key=lambda label: fits[label]["medians_us"][BASE_WORK])
    fixed = [f["fixed_work"] for f in fits.values() if f["fixed_work"] is not None]
    return {
        "heaviest_series": heaviest,
        "fixed_work_heaviest": fits[heaviest]["fixed_work"],
        "fixed_work_median": median(fixed) if fixed else None,
    }


def calibrated_work(fixed: float, work: float, share: float) -> int:
    """The work per pair that raises the CPU per operation by ``share`` from ``work``."""
    return round(work + share * (fixed + work))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="redline-calibrate-") as tmp:
        tree = Path(tmp) / "objectbuilder"
        shutil.copytree(EXAMPLE, tree, ignore=shutil.ignore_patterns("__pycache__"))
        by_work = {work: measure(work, args.runs, tree) for work in SETTINGS}
    fits = fit(by_work)
    result = {"settings": SETTINGS, "runs": args.runs, "fits": fits, **summary(fits)}
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
