"""The training data of a model for `redline watch` (watch.toml): the objectbuilder's CPU and
memory against its leg count, at the rates a running robot sends (legs at 30/s, poses at 10/s).

The leg counts go up and down from one set to the next: the longer feature windows (up to 10 s)
reach back into the previous set, and a sweep that only ever rose taught the model that heavier
traffic a few seconds ago means less CPU now than it does, so at run time it over-predicted
every time the crowd thinned (a false alarm in every start of the benchmark's runs)."""

from __future__ import annotations

import os

from redline.testing import FixedRate, Param, Phase, Publish, Table, TestCase, WithBackground
from test_objectbuilder import POSE, LegMessage

#: seconds per leg count (``REDLINE_SWEEP_SECONDS`` changes it): at 4 s the model had 44 steps
#: to learn from, and the alarm's threshold (twice the largest smoothed held-out residual) rested
#: on one of them: 19.6 % of a core from a run on a quiet host, too wide to see a stall; at 10 s,
#: 8.7 % (2026-11-24)
SECONDS = float(os.environ.get("REDLINE_SWEEP_SECONDS", "10.0"))
#: every count 1-11, each step up or down by 2 to 10 legs
ORDER = [1, 6, 11, 3, 9, 2, 7, 10, 4, 8, 5]


def load(seconds: float) -> WithBackground:
    return WithBackground(
        FixedRate(
            30,
            seconds,
            Publish("objectbuilder/legs", LegMessage(Param("legs")), encoding="application/json"),
        ),
        FixedRate(10, seconds + 1.0, Publish("objectbuilder/pose", POSE)),
    )


training = TestCase(
    "training",
    phases=[Phase("warmup", load(1.0), warmup=True), Phase("steady", load(SECONDS))],
    params=Table(["legs"], [(legs,) for legs in ORDER]),
)
