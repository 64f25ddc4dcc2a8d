"""The data of the resource-model evaluation (docs/prediction.md), after Wienke & Wrede's Section
6.2: the objectbuilder with 1, 2 and 4 worker threads, each

- swept over every leg count, leg rate and pose rate of the paper's conditions (legs 1-28 in steps
  of 3; legs at 10-50 Hz; poses at 2.5-20 Hz): each condition's training set is the segments
  whose parameters it lists (`benchmarks/eval_prediction.py` selects them), and
- sent the realistic replay (`realistic.py`: median 6 legs, rare peaks near 20, 30 Hz legs,
  10 Hz poses, 180 s), which no model is trained on.

Each instance listens under its own prefix (ob-t1, ob-t2, ob-t4) and is loaded alone. The
sweep's sets run in one shuffled order (a fixed seed): in the Cartesian order the load rises
with the leg count through the whole sweep, so the longer feature windows, which reach back into
the sets before, would rise with it and a model could not tell them apart from the set's own.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

from redline.testing import (
    Cartesian,
    FixedRate,
    Param,
    Phase,
    Publish,
    Replay,
    Table,
    TestCase,
    WithBackground,
)
from test_objectbuilder import POSE, LegMessage

#: seconds per parameter set (``REDLINE_SWEEP_SECONDS`` shortens it for a trial run)
SECONDS = float(os.environ.get("REDLINE_SWEEP_SECONDS", "2.0"))
LEGS = list(range(1, 29, 3))  # every condition's counts: d 1-22, l 1-13, m 1-28
LEG_RATES = [10, 20, 30, 40, 50]
POSE_RATES = [2.5, 5, 10, 15, 20]
REPLAY = Path(__file__).parent / "data" / "realistic.mcap"
SEED = 20261125


def shuffled(sets: Cartesian) -> Table:
    """The sets in one random order, the same in every run."""
    rows = [dict(params) for params in sets]
    random.Random(SEED).shuffle(rows)
    return Table(rows)


def sweep(threads: int) -> TestCase:
    prefix = f"ob-t{threads}"
    load = WithBackground(
        FixedRate(
            Param("leg_rate"),
            SECONDS,
            Publish(f"{prefix}/legs", LegMessage(Param("legs")), encoding="application/json"),
        ),
        FixedRate(Param("pose_rate"), SECONDS + 1.0, Publish(f"{prefix}/pose", POSE)),
    )
    return TestCase(
        f"sweep_t{threads}",
        phases=[Phase("steady", load)],
        params=shuffled(Cartesian(legs=LEGS, leg_rate=LEG_RATES, pose_rate=POSE_RATES)),
    )


sweep_t1, sweep_t2, sweep_t4 = sweep(1), sweep(2), sweep(4)


def replay(threads: int) -> TestCase:
    prefix = f"ob-t{threads}"
    return TestCase(
        f"replay_t{threads}",
        phases=[Phase("replay", Replay(REPLAY, remap={"objectbuilder": prefix}))],
        params=Table(["threads"], [(threads,)]),
    )


replay_t1, replay_t2, replay_t4 = replay(1), replay(2), replay(4)
