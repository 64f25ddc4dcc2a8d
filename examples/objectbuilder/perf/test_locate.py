"""Performance test of the objectbuilder's queryable: round trips and timeouts of ``locate``.

One test case: queries with a 2-leg message at 500 per second for 8 s after a warm-up, each
waited for up to 0.1 s. 4,000 queries a run let a change as rare as one timeout per 1,000
queries show against a history of none (Redline's timeout test wants about four in one run).
"""

from __future__ import annotations

from redline.testing import FixedRate, Phase, Query, TestCase
from test_objectbuilder import LegMessage

LOCATE = Query("objectbuilder/locate", LegMessage(2), timeout=0.1, encoding="application/json")

locate = TestCase(
    "locate",
    phases=[
        Phase("warmup", FixedRate(200, 0.5, LOCATE), warmup=True),
        Phase("steady", FixedRate(500, 8.0, LOCATE)),
    ],
)
