"""The order of a component page's charts (`redline.server.services.trend_view.chart_place`)."""

from __future__ import annotations

from redline.recording.driver import DRIVER_PROCESS, RECORDER_PROCESS
from redline.recording.format import HOST_PROCESS, OWN_PROCESS
from redline.server.services.trend_view import chart_place


def test_the_components_own_counters_come_first_and_redlines_last():
    """A trial's unfiltered component page opened with four flat recorder charts (the "@run"
    case) above the component's CPU."""
    keys = [
        ("@run", "run", RECORDER_PROCESS, "dropped"),
        ("legs", "steady", HOST_PROCESS, "cpu_percent"),
        ("legs", "steady", OWN_PROCESS, "cpu_percent"),
        ("legs", "steady", DRIVER_PROCESS, "FixedRate/Query(x):rtt_p50_us"),
        ("legs", "steady", "objectbuilder", "rss_bytes"),
        ("legs", "steady", "objectbuilder", "cpu_percent"),
        ("legs", "warmup", "objectbuilder", "cpu_percent"),
    ]
    assert sorted(keys, key=chart_place) == [
        ("legs", "steady", "objectbuilder", "cpu_percent"),
        ("legs", "steady", "objectbuilder", "rss_bytes"),
        ("legs", "steady", DRIVER_PROCESS, "FixedRate/Query(x):rtt_p50_us"),
        ("legs", "steady", HOST_PROCESS, "cpu_percent"),
        ("legs", "steady", OWN_PROCESS, "cpu_percent"),
        ("legs", "warmup", "objectbuilder", "cpu_percent"),
        ("@run", "run", RECORDER_PROCESS, "dropped"),
    ]
