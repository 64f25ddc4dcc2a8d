"""How long change detection takes, as ratios to a numpy pass over the same data (one run).

1. One execution of 500 series against its baseline with the default method.
2. Re-analysis of a history of 1,000 revisions x 100 series, every revision against the
   revisions just before it, with the default method; and E-divisive over a few of those
   histories (its cost per series, since it grows with the square of the history's length).

Run: .venv/bin/python benchmarks/bench_detect.py   (prints figures; not a test)
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from redline.detect.aggregate import compare_test
from redline.detect.changepoint import EDivisive
from redline.detect.evaluate import DEFAULT_METHOD, DETECTORS

BASELINE_SAMPLES, CANDIDATE_SAMPLES = 30, 10
REVISIONS, HISTORY_SERIES, PER_REVISION, BACK = 1000, 100, 5, 3


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
    base = {f"s{i}": rng.normal(100, 5, BASELINE_SAMPLES) for i in range(n_series)}
    cand = {f"s{i}": rng.normal(100 if i % 50 else 130, 5, CANDIDATE_SAMPLES)
            for i in range(n_series)}
    detector = DETECTORS[DEFAULT_METHOD]()
    detect = best_of(5, lambda: compare_test(detector, base, cand))
    reference = best_of(5, lambda: (mean_std_pass(base), mean_std_pass(cand)))
    print(f"1. one execution, {n_series} series ({BASELINE_SAMPLES} baseline + "
          f"{CANDIDATE_SAMPLES} candidate samples each), method {DEFAULT_METHOD}:")
    print(f"   detect {detect * 1e3:.1f} ms; numpy mean/std pass {reference * 1e3:.2f} ms; "
          f"ratio {detect / reference:.1f}x")


def reanalysis(rng: np.random.Generator) -> None:
    history = rng.normal(100, 5, (HISTORY_SERIES, REVISIONS, PER_REVISION))
    history[:, REVISIONS // 2:, :] *= 1.3
    detector = DETECTORS[DEFAULT_METHOD]()

    def detect_all() -> None:
        for s in range(HISTORY_SERIES):
            for r in range(1, REVISIONS):
                detector.compare(history[s, max(0, r - BACK):r].ravel(), history[s, r])

    def reference() -> None:
        for s in range(HISTORY_SERIES):
            for r in range(1, REVISIONS):
                np.mean(history[s, r]), np.std(history[s, r])

    detect, ref = best_of(1, detect_all), best_of(1, reference)
    comparisons = HISTORY_SERIES * (REVISIONS - 1)
    print(f"2. re-analysis, {REVISIONS} revisions x {HISTORY_SERIES} series "
          f"({comparisons} comparisons, baseline = {BACK} previous revisions), "
          f"method {DEFAULT_METHOD}:")
    print(f"   detect {detect:.2f} s ({detect / comparisons * 1e6:.0f} us per comparison); "
          f"numpy mean/std pass {ref:.3f} s; ratio {detect / ref:.1f}x")
    medians = np.median(history, axis=2)
    count = 3
    edivisive = best_of(1, lambda: [EDivisive().detect(medians[s]) for s in range(count)])
    ref_median = best_of(3, lambda: np.median(history[:count], axis=2))
    print(f"   E-divisive over {REVISIONS} revision medians: {edivisive / count:.2f} s per series "
          f"(199 permutations; x{HISTORY_SERIES} series = {edivisive / count * 100:.0f} s); "
          f"ratio to the median pass {edivisive / ref_median:.0f}x")


def main() -> None:
    rng = np.random.default_rng(0)
    one_execution(rng)
    reanalysis(rng)


if __name__ == "__main__":
    main()
