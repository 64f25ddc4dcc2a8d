"""The wait between two tries of a delivery (`redline.worker.deliver.backoff`): exponential in
the tries, with ±50 % jitter, and never more than six hours."""

from __future__ import annotations

from datetime import timedelta

import pytest
from redline.worker.deliver import MAX_BACKOFF, backoff

BASE = 30.0  # REDLINE_ALERT_RETRY_S's default
SAMPLES = 2000  # uniform draws: the chance that none falls in a tenth of the band is 0.9^2000


@pytest.mark.parametrize("tries", [1, 2, 3, 5, 9])
def test_the_wait_after_n_tries_is_base_times_two_to_the_n_minus_one_give_or_take_half(tries):
    middle = BASE * 2 ** (tries - 1)
    waits = [backoff(tries, BASE).total_seconds() for _ in range(SAMPLES)]
    assert middle * 0.5 <= min(waits) and max(waits) <= middle * 1.5
    # spread over the whole band, so receivers' retries do not come back together
    assert min(waits) < middle * 0.6 and max(waits) > middle * 1.4


def test_no_try_yet_waits_as_after_the_first():
    waits = [backoff(0, BASE).total_seconds() for _ in range(SAMPLES)]
    assert min(waits) >= BASE * 0.5 and max(waits) <= BASE * 1.5


def test_the_wait_is_at_most_six_hours_and_still_spread_out_there():
    """Before, every wait past the cap was exactly six hours: after a long outage, all of a
    receiver's deliveries came back at once."""
    waits = [backoff(tries, BASE) for tries in (10, 20, 10_000) for _ in range(SAMPLES)]
    assert max(waits) <= MAX_BACKOFF == timedelta(hours=6)
    assert min(waits) >= MAX_BACKOFF / 3  # the cap's band: 2 to 6 hours
    assert max(waits) > MAX_BACKOFF * 0.95 and min(waits) < MAX_BACKOFF * 0.4


def test_a_tiny_base_stays_tiny():
    assert all(backoff(1, 0.01) <= timedelta(seconds=0.015) for _ in range(SAMPLES))
