"""A series whose names cannot be stored is refused naming it, before the database is asked:
its key over Postgres's index row limit, or a name over its column's 200 characters (a
recording's names are not checked by an API schema: a 250-character case failed ingestion with a
DataError that left its job "uploaded" for good, a reviewer found)."""

from __future__ import annotations

import pytest
from redline.recording import SeriesKey
from redline.server.services.errors import Unstorable
from redline.server.services.ingestion import series_ids


@pytest.mark.parametrize(
    ("key", "said"),
    [
        (SeriesKey("c" * 250, "steady", "{}", "svc", "cpu"), "its case is 250 characters long"),
        (SeriesKey("c", "steady", "{}", "svc", "x" * 201), "its counter is 201 characters long"),
        (SeriesKey("c", "s", '{"p": "' + "é" * 1100 + '"}', "svc", "cpu"), "take 2217 bytes"),
        # an audit's: a NUL failed the insert and left the job "uploaded" for good, a control
        # character broke each line (a JUnit report, a mail) naming the series
        (SeriesKey("a\x00b", "s", "{}", "svc", "cpu"), "its case must not contain '\\\\x00'"),
        (SeriesKey("c", "s\u202e", "{}", "svc", "cpu"), "its phase must not contain"),
        (SeriesKey("c", "s", '{"p\\n": 1}', "svc", "cpu"), "its parameter name must not"),
        (SeriesKey("c", "s", '{"p": "a\\u0001"}', "svc", "cpu"), "its parameter p must not"),
        (SeriesKey("c", "s", '{"n": ' + "9" * 400 + "}", "svc", "cpu"), "n is beyond ±1e\\+30"),
    ],
)
def test_a_series_that_cannot_be_stored_is_refused_naming_it(key: SeriesKey, said: str) -> None:
    with pytest.raises(Unstorable, match=said) as refused:
        series_ids(None, 1, [key])  # type: ignore[arg-type]  # refused before any query
    assert isinstance(refused.value, ValueError)  # so an ingestion fails its job, not retries
