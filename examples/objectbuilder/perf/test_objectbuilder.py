"""Performance test of the objectbuilder: CPU and memory against leg count and message rate.

One test case, run for every combination of 2 or 8 legs per message and 10 or 40 messages per
second: a short warm-up, then a steady phase the analysis looks at. Every iteration publishes a
leg message and a robot pose.
"""

from __future__ import annotations

import json
import math
import time

from redline.testing import (
    Action,
    Cartesian,
    Context,
    FixedRate,
    Param,
    Phase,
    Publish,
    Sequence,
    Static,
    TestCase,
    resolve,
)


class LegMessage(Action):
    """A leg-detection message with ``legs`` legs, laid out in pairs 0.3 m apart.

    A custom action: store arguments (plain values or actions such as ``Param``) in attributes,
    and `resolve` them in ``run``. Redline finds the ``Param`` inside for validation by itself.
    """

    def __init__(self, legs: int | Action) -> None:
        self.legs = legs

    def run(self, ctx: Context) -> bytes:
        count = int(resolve(self.legs, ctx))
        legs = []
        for index in range(count):
            angle = (index // 2) * 2 * math.pi / max(1, count // 2)
            offset = 0.3 * (index % 2)
            legs.append({"x": 2.0 * math.cos(angle) + offset, "y": 2.0 * math.sin(angle)})
        return json.dumps({"stamp": time.time_ns(), "legs": legs}).encode()


POSE = Static(json.dumps({"x": 1.0, "y": 0.5, "theta": 0.1}))
STEP = Sequence(
    Publish("objectbuilder/legs", LegMessage(Param("legs")), encoding="application/json"),
    Publish("objectbuilder/pose", POSE, encoding="application/json"),
)

legs_and_rate = TestCase(
    "legs_and_rate",
    phases=[
        Phase("warmup", FixedRate(Param("rate"), 0.5, STEP), warmup=True),
        Phase("steady", FixedRate(Param("rate"), 2.0, STEP)),
    ],
    params=Cartesian(legs=[2, 8], rate=[10, 40]),
)
