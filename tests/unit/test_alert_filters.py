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


def test_an_alerts_summary_names_its_largest_change_with_its_parameters():
    """A trial's subject named the first series (+139.4 %) where +158.1 % was the largest, and
    the component twice: "objectbuilder: regression: objectbuilder cpu_percent ..."."""
    from redline.worker.messages import _summary

    def change(effect: float, legs: int, process: str = "objectbuilder") -> dict:
        return {
            "process": process,
            "counter": "cpu_percent",
            "effect": effect,
            "parameters": {"legs": legs, "rate": 40},
            "revision": {"title": "df29d8d18358"},
        }

    said = _summary("objectbuilder", "regression", [change(1.394, 2), change(1.581, 8)])
    assert said == (
        "objectbuilder: regression: cpu_percent +158.1 % [legs=8,rate=40] at df29d8d18358 "
        "and 1 more series"
    )
    other = _summary("objectbuilder", "improvement", [change(-0.2, 2, process="driver")])
    assert other.startswith("objectbuilder: improvement: driver cpu_percent -20.0 % [legs=2")


def test_an_alerts_chart_link_opens_the_changed_series_parameter_set_and_all():
    """A trial's alert linked to ?case=reads&phase=steady&process=kvstore&counter=pss_bytes,
    every parameter set's chart: the link now selects the changed one, as the page filters."""
    import json
    from types import SimpleNamespace
    from urllib.parse import parse_qsl, urlsplit

    from redline.server.models import Series
    from redline.server.services.trend_view import TrendView
    from redline.worker.messages import _chart_path

    params = {"rate": 150, "size": "2048", "mode": True}
    series = Series(case="reads", phase="steady", params=json.dumps(params, sort_keys=True),
                    process="kvstore", counter="pss_bytes")  # fmt: skip
    link = urlsplit(_chart_path("kv store", series))
    assert link.path == "/components/kv%20store"
    view = TrendView.from_query(dict(parse_qsl(link.query)))
    same = SimpleNamespace(case="reads", phase="steady", process="kvstore", counter="pss_bytes")
    assert view.selects(SimpleNamespace(**vars(same), params=params))
    assert not view.selects(SimpleNamespace(**vars(same), params={**params, "rate": 50}))


def test_min_effect_keeps_a_change_from_zero_and_a_counts_rate_and_names_it_largest():
    """A review: a change from a zero baseline has no ratio (its effect null) and a count's
    rate moves by points (timeouts 0 -> 0.6 % of queries: 0.006); `min_effect` 0.05 dropped
    both, and the subject ranked the one from zero smallest."""
    from types import SimpleNamespace

    from redline.worker.alerts import wants
    from redline.worker.messages import _summary

    subscription = SimpleNamespace(direction="regression", counters=[], min_effect=0.05)

    def change(effect: float | None, counter: str = "cpu_percent", method: str = "ks") -> dict:
        return {"process": "svc", "counter": counter, "effect": effect, "method": method,
                "parameters": {}, "revision": {"title": "r7"}}  # fmt: skip

    assert wants(subscription, True, change(None))
    assert wants(
        subscription, True, change(0.006, "FixedRate/Query(svc/get):timeouts", "count_rate")
    )
    assert wants(subscription, True, change(0.05)) and not wants(subscription, True, change(0.049))
    said = _summary("svc", "regression", [change(0.8), change(None, "cpu_system_percent")])
    assert said == "svc: regression: cpu_system_percent from 0 at r7 and 1 more series"
