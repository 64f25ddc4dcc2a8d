"""Which revision rows of a component page name an open regression (`open_in`)."""

from __future__ import annotations

from datetime import UTC, datetime

from redline.server.schemas.regressions import RegressionOut
from redline.server.services.open_regressions import open_in

NEWEST_FIRST = ["r6", "r5", "r4", "r3", "r2"]


def regression(ident: int, good: str, bad: str, confirmation: str, state: str) -> RegressionOut:
    now = datetime(2026, 12, 7, tzinfo=UTC)
    return RegressionOut(
        id=ident,
        component="builder",
        good_revision=good,
        bad_revision=bad,
        state=state,
        confirmation=confirmation,
        confirmation_reason="",
        methods=["execution_shift"],
        detections=1,
        created=now,
        updated=now,
    )


def test_a_range_marks_the_revisions_after_its_good_one_up_to_its_bad_one() -> None:
    marked = open_in(NEWEST_FIRST, [regression(1, "r3", "r5", "confirmed", "new")])
    assert {title: [r.id for r in found] for title, found in marked.items()} == {
        "r5": [1],
        "r4": [1],
    }


def test_a_good_revision_older_than_those_listed_marks_down_to_the_oldest_listed() -> None:
    marked = open_in(NEWEST_FIRST, [regression(2, "r1", "r3", "suspected", "acknowledged")])
    assert sorted(marked) == ["r2", "r3"]


def test_dropped_withdrawn_triaged_away_or_older_regressions_mark_nothing() -> None:
    listed = [
        regression(3, "r5", "r6", "not_confirmed", "new"),
        regression(4, "r5", "r6", "withdrawn", "new"),
        regression(5, "r5", "r6", "confirmed", "fixed"),
        regression(6, "r5", "r6", "confirmed", "false_positive"),
        regression(7, "r0", "r1", "confirmed", "new"),  # older than the rows listed
    ]
    assert open_in(NEWEST_FIRST, listed) == {}
