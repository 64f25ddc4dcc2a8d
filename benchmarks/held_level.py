"""How often a held level (`ExecutionShift.held`) flags on the corpora, against one revision's
run alone: every build of every judged series, first execution only (one execution a revision,
the service's default), asked as the worker asks it (`redline.worker.held_level`): the 7
builds before it (the default window of 10 less the 3 after it), `HELD_AFTER` from it on.

A position is unchanged when no labelled change lies in that stretch; a change is found when
the position at a labelled change flags. Beside it, the changed build's one run against the 10
before it, at the same threshold. Run: ``.venv/bin/python benchmarks/held_level.py [--json F]``.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from redline.detect.corpus import first_executions, load_corpus, measures, series_builds
from redline.detect.execution_shift import HELD_AFTER, ExecutionShift, execution_values

CORPORA = ("benchmarks/corpus/objectbuilder", "benchmarks/corpus/objectbuilder-busy-host", "sap")
BEFORE, WINDOW = 7, 10


def evaluate(name: str) -> dict[str, float | int | str]:
    judge = ExecutionShift().confirmed()
    unchanged = held_false = alone_false = changes = held_found = alone_found = either = 0
    for series, label, builds in series_builds(first_executions(load_corpus(name), 1)):
        counted = measures(series, label)
        if not counted.judged or counted.count:
            continue
        values = np.array([execution_values(runs)[0] for _, runs in builds])
        changed = {i for i, (build, _) in enumerate(builds) if build in label.change_builds}
        for k in range(BEFORE, len(values) - HELD_AFTER + 1):
            if changed & (set(range(k - BEFORE, k + HELD_AFTER)) - {k}):
                continue  # another change in the stretch
            held = judge.held(values[k - BEFORE : k], values[k : k + HELD_AFTER]).flagged
            alone = judge.compare(values[max(0, k - WINDOW) : k], values[k : k + 1]).flagged
            if k in changed:
                changes += 1
                held_found, alone_found = held_found + held, alone_found + alone
                either += held or alone
            else:
                unchanged += 1
                held_false, alone_false = held_false + held, alone_false + alone
    return {
        "corpus": name,
        "unchanged_positions": unchanged,
        "held_flags_unchanged": held_false,
        "one_run_flags_unchanged": alone_false,
        "changes": changes,
        "held_found": held_found,
        "one_run_found": alone_found,
        "either_found": either,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args()
    results = [evaluate(name) for name in CORPORA]
    for r in results:
        print(
            f"{r['corpus']}: unchanged {r['unchanged_positions']}, flagged held "
            f"{r['held_flags_unchanged']} / one run {r['one_run_flags_unchanged']}; changes "
            f"{r['changes']}, found held {r['held_found']} / one run {r['one_run_found']} / "
            f"either {r['either_found']}"
        )
    if args.json:
        with open(args.json, "w") as out:
            json.dump(
                {"held_after": HELD_AFTER, "before": BEFORE, "corpora": results}, out, indent=1
            )


if __name__ == "__main__":
    main()
