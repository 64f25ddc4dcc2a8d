"""Five clean minutes of a running robot's traffic for `redline watch` (watch-clean.toml): the
replay on which a model fitted on watch.toml's sweep must raise nothing
(tests/integration/test_watch_replay.py). Legs at 30/s whose count wanders around 9 within the
1-11 the model was trained on, as `tests/support/watching.live_objectbuilder` sends them live;
poses at 10/s. ``REDLINE_CLEAN_SECONDS`` changes the length."""

from __future__ import annotations

import os
import random

from redline.testing import Action, Context, FixedRate, Phase, Publish, TestCase, WithBackground
from test_objectbuilder import POSE, LegMessage

SECONDS = float(os.environ.get("REDLINE_CLEAN_SECONDS", "300"))
SEED = 20261124


class Crowd(Action):
    """The leg count of the next message: a crowd that wanders slowly around 9 legs, within the
    training sweep's 1-11."""

    def __init__(self, seed: int = SEED) -> None:
        self.random = random.Random(seed)
        self.level = 9.0

    def run(self, ctx: Context) -> int:
        self.level += 0.02 * (9.0 - self.level) + self.random.gauss(0, 0.25)
        return max(1, min(11, round(self.level + self.random.gauss(0, 0.7))))


def load(seconds: float) -> WithBackground:
    return WithBackground(
        FixedRate(
            30,
            seconds,
            Publish("objectbuilder/legs", LegMessage(Crowd()), encoding="application/json"),
        ),
        FixedRate(10, seconds + 1.0, Publish("objectbuilder/pose", POSE)),
    )


clean = TestCase(
    "clean",
    phases=[Phase("warmup", load(2.0), warmup=True), Phase("steady", load(SECONDS))],
)
