"""How long change detection takes, as ratios to a numpy pass over the same data (one run).

1. One new execution of 500 series against its baseline with the default method: each series'
   samples reduced as the method judges them (one median per execution for execution_shift),
   the baseline's revisions likewise, then the detector.
2. Re-analysis of a history of 1,000 revisions x 100 series (3 executions of 10 samples per
   revision), every revision against its ``recent`` baseline (restarting where the method
   flagged), with the default method; and E-divisive over a few of those histories (its cost
   per series, since it grows with the square of the history's length).

Run: .venv/bin/python benchmarks/bench_detect.py   (prints figures; not a test)
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from redline.detect.baseline import DEFAULT_WINDOW, recent_depth
from redline.detect.changepoint import EDivisive
from redline.detect.execution_shift import values_for
from redline.detect.registry import DEFAULT_METHOD, DETECTORS

SAMPLES, EXECUTIONS, BASELINE_REVISIONS = 20, 3, 5
REVISIONS, HISTORY_SERIES = 1000, 100


def best_of(repeats: int, work: Callable[[], object]) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        work()
        times.append(time.perf_counter() - start)
    return min(times)


def mean_std_pass(series: dict[str, np.ndarray]) -> None:
    for values in series.values():
        float(np.mean(values)), float(np.std(values))


def one_execution(rng: np.random.Generator, n_series: int = 500) -> None:
    base = [
        [
            [rng.normal(100, 5, SAMPLES) for _ in range(EXECUTIONS)]
            for _ in range(BASELINE_REVISIONS)
        ]
        for _ in range(n_series)
    ]
    cand = [[rng.normal(100 if i % 50 else 130, 5, SAMPLES)] for i in range(n_series)]
    detector = DETECTORS[DEFAULT_METHOD]()

    def detect() -> None:
        for series in range(n_series):
            baseline = np.concatenate([values_for(detector, runs) for runs in base[series]])
            detector.compare(baseline, values_for(detector, cand[series]))

    def reference() -> None:
        for series in range(n_series):
            for runs in (*base[series], cand[series]):
                for run in runs:
                    float(np.mean(run)), float(np.std(run))

    took, ref = best_of(5, detect), best_of(5, reference)
    print(
        f"1. one execution, {n_series} series ({SAMPLES} samples; baseline "
        f"{BASELINE_REVISIONS} revisions x {EXECUTIONS} executions), method {DEFAULT_METHOD}:"
    )
    print(
        f"   detect {took * 1e3:.1f} ms; numpy mean/std pass {ref * 1e3:.1f} ms; "
        f"ratio {took / ref:.1f}x"
    )


def reanalysis(rng: np.random.Generator) -> None:
    history = rng.normal(100, 5, (HISTORY_SERIES, REVISIONS, EXECUTIONS, SAMPLES // 2))
    history *= rng.normal(1, 0.03, (HISTORY_SERIES, REVISIONS, EXECUTIONS, 1))  # run-to-run
    history[:, REVISIONS // 2 :] *= 1.3
    detector = DETECTORS[DEFAULT_METHOD]()

    def detect_all() -> int:
        flags = 0
        for s in range(HISTORY_SERIES):
            values = [values_for(detector, list(history[s, r])) for r in range(REVISIONS)]
            last = None
            for r in range(1, REVISIONS):
                sizes = [len(values[j]) for j in range(r - 1, max(-1, r - 1 - DEFAULT_WINDOW), -1)]
                depth = recent_depth(
                    sizes,
                    detector.baseline_values,
                    DEFAULT_WINDOW,
                    None if last is None else r - 1 - last,
                )
                if detector.compare(np.concatenate(values[r - depth : r]), values[r]).flagged:
                    last, flags = r, flags + 1
        return flags

    def reference() -> None:
        for s in range(HISTORY_SERIES):
            for r in range(1, REVISIONS):
                np.mean(history[s, r]), np.std(history[s, r])

    start = time.perf_counter()
    flags = detect_all()
    detect = time.perf_counter() - start
    ref = best_of(1, reference)
    comparisons = HISTORY_SERIES * (REVISIONS - 1)
    print(
        f"2. re-analysis, {REVISIONS} revisions x {HISTORY_SERIES} series "
        f"({comparisons} comparisons, recent baseline), method {DEFAULT_METHOD}:"
    )
    print(
        f"   detect {detect:.2f} s ({detect / comparisons * 1e6:.0f} us per comparison; "
        f"{flags} flags, {HISTORY_SERIES} planted); numpy mean/std pass {ref:.3f} s; "
        f"ratio {detect / ref:.1f}x"
    )
    medians = np.median(history.reshape(HISTORY_SERIES, REVISIONS, -1), axis=2)
    count = 3
    edivisive = best_of(1, lambda: [EDivisive().detect(medians[s]) for s in range(count)])
    ref_median = best_of(
        3, lambda: np.median(history[:count].reshape(count, REVISIONS, -1), axis=2)
    )
    print(
        f"   E-divisive over {REVISIONS} revision medians: {edivisive / count:.2f} s per series "
        f"(199 permutations; x{HISTORY_SERIES} series = {edivisive / count * 100:.0f} s); "
        f"ratio to the median pass {edivisive / ref_median:.0f}x"
    )


def main() -> None:
    rng = np.random.default_rng(0)
    one_execution(rng)
    reanalysis(rng)


if __name__ == "__main__":
    main()
