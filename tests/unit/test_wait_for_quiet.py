"""`redline.agent.quiet.wait_for_quiet`'s rule on a given sequence of host loads (the real
host's, with a core spinning, in tests/integration/test_quiet.py)."""

from __future__ import annotations

from redline.agent.quiet import QUIET_SAMPLES, wait_for_quiet


def _waits(loads: list[float | None], most_s: float = 90.0) -> tuple[float | None, list[float]]:
    given = iter(loads)
    slept: list[float] = []
    waited = wait_for_quiet(30.0, most_s, sleep=slept.append, load=lambda _: next(given))
    return waited, slept


def test_it_waits_for_quiet_seconds_in_a_row_and_gives_up_at_its_bound():
    assert QUIET_SAMPLES == 3
    # the first sample has no rate; a quiet second between busy ones starts the count again
    waited, slept = _waits([None, 96.0, 12.0, 95.0, 20.0, 29.9, 5.0, 99.0])
    assert waited == 6.0 and slept == [1.0] * 6
    assert _waits([None, 5.0, 4.0, 3.0])[0] == 3.0  # quiet already: three seconds
    assert _waits([None, None, 5.0, 5.0, 5.0])[0] == 4.0  # no rate counts as not quiet
    waited, slept = _waits([None] + [100.0] * 10, most_s=5)
    assert waited is None and len(slept) == 5
    assert _waits([], most_s=0) == (0.0, [])  # `--quiet-wait 0`: at once, as before
