"""The objectbuilder's full sweep: the paper's three kinds of sweep, and 1/2/4 worker threads.

- ``leg_count``: 1 to 16 legs per message at 20 messages/s (work grows with the square).
- ``leg_rate``: 4 legs per message at 10 to 80 messages/s.
- ``pose_rate``: 4 legs at 20 messages/s while poses arrive at 10 to 200 per second in the
  background (the pose thread's share of the cost).
- ``threads``: 8 legs at 40 messages/s against the 1-, 2- and 4-thread instances.

The sweeps run on the 2-thread instance; every instance listens under its own key prefix.
"""

from __future__ import annotations

from redline.testing import (
    Cartesian,
    FixedRate,
    Param,
    Phase,
    Publish,
    Sequence,
    Table,
    TestCase,
    WithBackground,
)
from test_objectbuilder import POSE, LegMessage

SECONDS = 2.0


def legs_then_pose(prefix: str) -> Sequence:
    """One iteration of the default test: a leg message, then a pose."""
    return Sequence(
        Publish(f"{prefix}/legs", LegMessage(Param("legs")), encoding="application/json"),
        Publish(f"{prefix}/pose", POSE, encoding="application/json"),
    )


def steady(prefix: str) -> list[Phase]:
    """A short warm-up, then the measured phase, both at ``rate`` messages/s."""
    return [
        Phase("warmup", FixedRate(Param("rate"), 0.5, legs_then_pose(prefix)), warmup=True),
        Phase("steady", FixedRate(Param("rate"), SECONDS, legs_then_pose(prefix))),
    ]


leg_count = TestCase("leg_count", steady("ob-t2"), Cartesian(legs=[1, 2, 4, 8, 16], rate=[20]))

leg_rate = TestCase("leg_rate", steady("ob-t2"), Cartesian(legs=[4], rate=[10, 20, 40, 80]))

pose_rate = TestCase(
    "pose_rate",
    phases=[
        Phase(
            "steady",
            WithBackground(
                FixedRate(
                    20, SECONDS, Publish("ob-t2/legs", LegMessage(4), encoding="application/json")
                ),
                FixedRate(Param("pose_rate"), SECONDS + 1.0, Publish("ob-t2/pose", POSE)),
            ),
        )
    ],
    params=Cartesian(pose_rate=[10, 50, 100, 200]),
)

threads = TestCase(
    "threads",
    phases=[
        Phase(
            "steady",
            FixedRate(
                40,
                SECONDS,
                Sequence(
                    Publish(Param("legs_key"), LegMessage(8), encoding="application/json"),
                    Publish(Param("pose_key"), POSE, encoding="application/json"),
                ),
            ),
        )
    ],
    params=Table(
        ["threads", "legs_key", "pose_key"],
        [(n, f"ob-t{n}/legs", f"ob-t{n}/pose") for n in (1, 2, 4)],
    ),
)
