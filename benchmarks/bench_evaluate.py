"""`redline evaluate` on a history the size of a real held-out set, against the detectors' own time.

The corpus is generated: 466 series x 645 builds (300,124 units), each build 3 repeated
measurements without an execution column (every sample its own execution, as SAP's set), a
level that steps now and then and noise of 3 %, two labelled changes in every fourth series.
For each per-build method it times the whole evaluation (`evaluate_corpus`: grouping the
corpus, walking every series with the `recent` baseline, judging, scoring) and, in the same run,
the detector alone on the same baselines and candidates (`judge_series` over the units the walk
produced): the ratio says what the evaluation costs around the statistics. It also times the
grouping of the corpus into builds and executions against the pandas group-by it replaced.
Goal (issue 12): <= 60 s per per-build method for 300,000 units on these 2 cores.

Run: .venv/bin/python benchmarks/bench_evaluate.py [METHOD ...]   (default: execution_shift ks)
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pandas as pd
from redline.detect.corpus import Corpus, SeriesLabel, series_builds
from redline.detect.evaluate import counter_of, evaluate_corpus, walk
from redline.detect.registry import EVALUATED
from redline.detect.verdict import judge_series

SERIES, BUILDS, SAMPLES = 466, 645, 3
GOAL_S = 60.0


def generated() -> Corpus:
    rng = np.random.default_rng(12)
    frames, labels = [], {}
    for index in range(SERIES):
        level = np.full(BUILDS, 100.0)
        changes: list[int] = []
        if index % 4 == 0:
            changes = sorted(rng.choice(np.arange(50, BUILDS - 50), 2, replace=False).tolist())
            for change in changes:
                level[change:] *= rng.choice([0.8, 1.2])
        values = rng.normal(np.repeat(level, SAMPLES), 3.0)
        name = f"s{index:03d}"
        frames.append(
            pd.DataFrame(
                {
                    "series": name,
                    "build": np.repeat(np.arange(BUILDS), SAMPLES),
                    "value": values,
                    "execution": np.tile(np.arange(SAMPLES), BUILDS),
                }
            )
        )
        labels[name] = (
            SeriesLabel("regression", changes[0], tuple(changes[1:]))
            if changes
            else SeriesLabel("Stable")
        )
    return Corpus("generated", pd.concat(frames, ignore_index=True), labels)


def grouped_by_pandas(corpus: Corpus):  # noqa: ANN201 - the reference, as it was
    """How `series_builds` grouped before (a pandas group-by per build and execution)."""
    for series, frame in corpus.measurements.groupby("series", sort=True):
        builds = []
        for build, part in frame.groupby("build", sort=True):
            executions = [g["value"].to_numpy() for _, g in part.groupby("execution")]
            builds.append((int(build), executions))
        yield str(series), builds


def detectors_alone(name: str, corpus: Corpus) -> float:
    """The detector's time on the same baselines and candidates the evaluation judged."""
    detector = EVALUATED[name]()
    units = [unit for unit, _ in walk(detector, corpus)]
    start = time.perf_counter()
    for unit in units:
        baseline, candidate = unit.baseline, unit.candidate
        if detector.ndim == 2:
            baseline, candidate = baseline[:, None], candidate[:, None]
        judge_series(detector, counter_of(unit.series), baseline, candidate)
    return time.perf_counter() - start


def main() -> None:
    methods = sys.argv[1:] or ["execution_shift", "ks"]
    corpus = generated()
    units = SERIES * (BUILDS - 1)
    rows = len(corpus.measurements)
    print(f"corpus: {SERIES} series x {BUILDS} builds = {units} units, {rows} rows")
    start = time.perf_counter()
    grouped = list(series_builds(corpus))
    arrays = time.perf_counter() - start
    start = time.perf_counter()
    reference = list(grouped_by_pandas(corpus))
    pandas = time.perf_counter() - start
    assert [(s, [b for b, _ in builds]) for s, _, builds in grouped] == [
        (s, [b for b, _ in builds]) for s, builds in reference
    ]
    print(
        f"grouping into builds and executions: {arrays:.1f} s; the former pandas group-by per "
        f"build and execution: {pandas:.1f} s ({pandas / arrays:.0f}x)"
    )
    for name in methods:
        start = time.perf_counter()
        scores = evaluate_corpus(corpus, [name])[name]
        whole = time.perf_counter() - start
        alone = detectors_alone(name, corpus)
        print(
            f"{name}: evaluation {whole:.1f} s ({units / whole:,.0f} units/s), detector alone "
            f"{alone:.1f} s, ratio {whole / alone:.2f}x; goal <= {GOAL_S:.0f} s: "
            f"{'met' if whole <= GOAL_S else 'NOT met'} (TP {scores.tp}, FP {scores.fp})"
        )


if __name__ == "__main__":
    main()
