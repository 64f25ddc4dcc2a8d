"""Table 4 of Wienke & Wrede, reproduced with the objectbuilder (issue 15; docs/prediction.md).

    .venv/bin/python benchmarks/eval_prediction.py RECORDING [--json OUT]

RECORDING is a run of ``examples/objectbuilder/perf/prediction.toml`` (about 35 minutes):

    cd examples/objectbuilder/perf && redline run prediction.toml --out prediction.mcap

For each worker-thread configuration (1, 2, 4) and each of the 27 combinations of the paper's
test conditions (leg count d/l/m, leg rate d/r/dr, pose rate d/r/dr), a model of the instance's
CPU is fitted on the sweep segments whose parameters the condition lists, and scored on the
realistic replay (which no model saw): RMSE in % of one core, and in % of predicting the replay's
mean (the paper's baseline). Prints the table beside the paper's, and the influence of each
parameter's condition (the paper's Figure 9) as mean ratios. The goal: a mean ratio of at most
30 % across the conditions (the paper's was 48 %).
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import sys
import time
from pathlib import Path

from redline.predict.dataset import DataError, dataset, read_run
from redline.predict.features import WINDOWS
from redline.predict.model import ModelFile
from redline.recording.reader import Segment

LEGS = {"d": list(range(1, 23, 3)), "l": list(range(1, 14, 3)), "m": list(range(1, 29, 3))}
LEG_RATES = {"d": [30], "r": [10, 20, 40, 50], "dr": [10, 20, 30, 40, 50]}
POSE_RATES = {"d": [10], "r": [2.5, 5, 15, 20], "dr": [2.5, 5, 10, 15, 20]}
#: the paper's Table 4: threads -> (mean RMSE %, mean ratio %, min RMSE, min ratio, l/dr/dr
#: RMSE, l/dr/dr ratio)
PAPER = {1: (10.2, 54.6, 7.3, 39.0, 7.4, 39.5), 2: (19.7, 40.0, 12.6, 25.6, 14.7, 29.8),
         4: (44.5, 49.7, 26.5, 29.6, 28.3, 31.7)}  # fmt: skip


def chosen(segment: Segment, case: str, legs: str, leg_rate: str, pose_rate: str) -> bool:
    params = segment.params
    return (
        segment.case == case
        and params.get("legs") in LEGS[legs]
        and params.get("leg_rate") in LEG_RATES[leg_rate]
        and params.get("pose_rate") in POSE_RATES[pose_rate]
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("--json", type=Path, help="write every result here")
    parser.add_argument(
        "--windows",
        type=float,
        nargs="+",
        default=list(WINDOWS),
        help="feature window lengths in seconds (default: %(default)s)",
    )
    args = parser.parse_args()
    run = read_run(args.recording)
    print(
        f"{len(run.disturbed)} of {len(run.segments)} segments disturbed by other load "
        "(left out of training and scoring)"
    )

    results = []
    for threads in (1, 2, 4):
        process, prefix = f"objectbuilder-t{threads}", f"ob-t{threads}/"
        for legs, leg_rate, pose_rate in itertools.product(LEGS, LEG_RATES, POSE_RATES):
            started = time.perf_counter()
            condition = f"{legs}/{leg_rate}/{pose_rate}"
            try:
                train = dataset(
                    [run],
                    process,
                    keep=lambda s, c=(legs, leg_rate, pose_rate), t=threads: chosen(
                        s, f"sweep_t{t}", *c
                    ),
                    keys=lambda key, p=prefix: key.startswith(p),
                    windows=args.windows,
                )
                model = ModelFile.fit(train, targets=("cpu_percent",))
                test = dataset(
                    [run],
                    process,
                    spec=model.spec,
                    keep=lambda s, t=threads: s.case == f"replay_t{t}",
                )
            except DataError as exc:
                print(f"t{threads} {condition}: {exc}", file=sys.stderr)
                continue
            found = model.score(test)["cpu_percent"]
            results.append(
                {
                    "threads": threads,
                    "legs": legs,
                    "leg_rate": leg_rate,
                    "pose_rate": pose_rate,
                    "train_steps": len(train.x),
                    "test_steps": len(test.x),
                    "rmse": found["rmse"],
                    "baseline_rmse": found["baseline_rmse"],
                    "ratio": found["ratio"],
                    "cv_ratio": model.metrics["cpu_percent"]["cv_ratio"],
                    "seconds": time.perf_counter() - started,
                }
            )
            print(
                f"t{threads} {condition:>8}: RMSE {found['rmse']:6.2f} % of a core = "
                f"{found['ratio']:6.1%} of the baseline ({len(train.x)} training steps)",
                flush=True,
            )
    print("\n| threads | ø RMSE % | ø ratio % | min RMSE % | min ratio % | l/dr/dr RMSE % | "
          "l/dr/dr ratio % | paper ø / min / l-dr-dr ratio % |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for threads in (1, 2, 4):
        rows = [r for r in results if r["threads"] == threads]
        if not rows:
            continue
        best = min(rows, key=lambda r: r["ratio"])
        insight = next(
            (r for r in rows if (r["legs"], r["leg_rate"], r["pose_rate"]) == ("l", "dr", "dr")),
            None,
        )
        paper = PAPER[threads]
        print(
            f"| {threads} | {statistics.mean(r['rmse'] for r in rows):.1f} | "
            f"{100 * statistics.mean(r['ratio'] for r in rows):.1f} | {best['rmse']:.1f} | "
            f"{100 * best['ratio']:.1f} | "
            + (f"{insight['rmse']:.1f} | {100 * insight['ratio']:.1f}" if insight else "– | –")
            + f" | {paper[1]} / {paper[3]} / {paper[5]} |"
        )
    if results:
        mean = statistics.mean(r["ratio"] for r in results)
        best = min(results, key=lambda r: r["ratio"])
        worst = max(results, key=lambda r: r["ratio"])
        print(
            f"\nmean ratio across all {len(results)} models: {mean:.1%} (goal ≤ 30 %; paper 48 %)"
        )
        for name, row in (("best", best), ("worst", worst)):
            print(
                f"{name}: {row['threads']} thread(s), legs {row['legs']}, leg rate "
                f"{row['leg_rate']}, pose rate {row['pose_rate']}: {row['ratio']:.1%}"
            )
        print("\ninfluence of each parameter's condition (mean ratio, per thread count):")
        for parameter in ("legs", "leg_rate", "pose_rate"):
            for value in dict.fromkeys(r[parameter] for r in results):
                by_threads = [
                    statistics.mean(
                        r["ratio"]
                        for r in results
                        if r[parameter] == value and r["threads"] == threads
                    )
                    for threads in (1, 2, 4)
                    if any(r[parameter] == value and r["threads"] == threads for r in results)
                ]
                print(f"  {parameter} {value}: " + " / ".join(f"{v:.1%}" for v in by_threads))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
