"""Which changes a subscription's ``counters`` hear of (`redline.worker.alerts.told_of`)."""

from __future__ import annotations

from redline.worker.alerts import told_of


def test_a_counter_is_heard_of_by_its_name_and_a_driver_metric_by_the_metric_alone():
    """A trial copied the docs' example ("cpu", "rss"): its subscription never fired, the
    series being cpu_percent and rss_bytes; a driver metric's counter carries its action's
    path, which no one subscribing to round trips should have to spell."""
    assert told_of("cpu_percent", ["cpu_percent", "rss_bytes"])
    assert not told_of("cpu_percent", ["cpu"])  # names are exact: the docs now give the real ones
    metric = "FixedRate/Query(svc/get):rtt_p90_us"
    assert told_of(metric, ["rtt_p90_us"]) and told_of(metric, [metric])
    assert not told_of(metric, ["rtt_p50_us"]) and not told_of("rss_bytes", ["rtt_p90_us"])
