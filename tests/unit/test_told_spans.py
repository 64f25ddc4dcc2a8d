"""What an alert subscription was told is compared by ranges of revisions, each end a (sort key,
id): revisions of one sort key (commits of one second) keep their reported order, so the range
(r4, r5] of two such revisions is not empty, and a change told there is known again."""

from __future__ import annotations

from redline.worker.told import overlaps


def test_a_range_between_revisions_of_one_sort_key_overlaps_itself() -> None:
    told = (("1795776531", 4), ("1795776531", 5))
    assert overlaps(told, told)
    assert overlaps(told, (("1795776531", 3), ("1795776532", 6)))
    assert not overlaps(told, (("1795776531", 5), ("1795776532", 6)))  # (r5, r6] comes after
    by_keys_alone = ("1795776531", "1795776531")
    assert not overlaps(by_keys_alone, by_keys_alone)  # what the keys alone made of it
