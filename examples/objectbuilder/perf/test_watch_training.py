"""The training data of a model for `redline watch` (watch.toml): the objectbuilder's CPU and
memory against its leg count, at the rates a running robot sends (legs at 30/s, poses at 10/s)."""

from __future__ import annotations

import os

from redline.testing import Cartesian, FixedRate, Param, Phase, Publish, TestCase, WithBackground
from test_objectbuilder import POSE, LegMessage

#: seconds per leg count (``REDLINE_SWEEP_SECONDS`` changes it)
SECONDS = float(os.environ.get("REDLINE_SWEEP_SECONDS", "4.0"))


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
    params=Cartesian(legs=list(range(1, 12))),
)
