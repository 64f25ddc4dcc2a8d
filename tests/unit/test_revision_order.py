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


def test_digits_of_any_script_are_numbers_and_long_runs_keep_their_order():
    """A trial from outside saw Arabic-Indic digits and runs of 100 digits misordered."""
    assert order_key("\u0661\u0660") == order_key("10")  # Arabic-Indic ten
    assert order_key("\u0669") < order_key("\u0661\u0660")  # nine before ten
    assert order_key("\u096f") == order_key("9")  # Devanagari nine
    long = ["9" * 98, "1" + "0" * 98, "9" * 99, "1" + "0" * 99, "9" * 150, "1" + "0" * 199]
    assert sorted(long, key=order_key) == long  # numeric order across the 99-digit boundary
    assert sorted(["7", "1" + "0" * 120], key=order_key) == ["7", "1" + "0" * 120]


def test_a_sort_key_is_natural_order_not_a_number_parser():
    """Documented, not parsed: "1e3" is 1, e, 3 (before "2"), and versions order as versions."""
    assert order_key("1e3") < order_key("2")
    assert sorted(["1.10", "1.9", "1.9.1"], key=order_key) == ["1.9", "1.9.1", "1.10"]
