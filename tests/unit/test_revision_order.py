"""Revisions are ordered by their sort key, digit runs compared as numbers."""

from __future__ import annotations

from redline.server.services.revisions import order_key


def test_order_key_orders_digit_runs_numerically():
    keys = ["10", "9", "r10", "r2", "1.10", "1.9", "009", "b", "a"]
    ordered = sorted(keys, key=order_key)
    assert ordered.index("9") < ordered.index("10")
    assert ordered.index("r2") < ordered.index("r10")
    assert ordered.index("1.9") < ordered.index("1.10")
    assert order_key("009") == order_key("9") and ordered.index("a") < ordered.index("b")
