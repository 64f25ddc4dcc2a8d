"""Text a request stores and the pages, `redline token list` and e-mails show in one line: a
control, format or line-separator character in it is refused, naming the character and where
(a trial stored CR/LF, U+0085 and U+202E in sort keys, branches, labels, counters and titles)."""

from __future__ import annotations

import json
import re
from typing import Any

import pytest
from pydantic import BaseModel, ValidationError
from redline.server.app import _huge_path_id
from redline.server.schemas.alerts import SubscriptionCreate
from redline.server.schemas.components import ComponentCreate, ComponentSettings
from redline.server.schemas.imports import ResultsImport
from redline.server.schemas.jobs import HostRequest, RegisterRequest
from redline.server.schemas.revisions import RevisionCreate
from redline.server.services.errors import BadRequest
from redline.server.services.lnt import parse_lnt
from starlette.requests import Request

REVISION = {"component": "c", "title": "r1", "sort_key": "1", "commit": "abc"}
VALUE = {"case": "t", "counter": "cpu", "values": [1.0]}
IMPORT = {"component": "c", "revision": "r1", "sort_key": "1", "results": [VALUE]}
MAIL = {"kind": "email", "address": "a@example.org"}
#: each model, a valid body, and a field of it set (through ``put``) to the bad text
CASES: list[tuple[type[BaseModel], dict[str, Any], str, Any]] = [
    (RevisionCreate, REVISION, "sort_key", lambda bad: bad),
    (RevisionCreate, REVISION, "branch", lambda bad: bad),
    (RevisionCreate, REVISION, "title", lambda bad: bad),
    (ComponentCreate, {"name": "c"}, "branch", lambda bad: bad),
    (ComponentCreate, {"name": "c"}, "host_labels", lambda bad: [bad]),
    (ComponentSettings, {}, "branch", lambda bad: bad),
    (ComponentSettings, {}, "host_labels", lambda bad: ["ok", bad]),
    (ResultsImport, IMPORT, "host", lambda bad: bad),
    (ResultsImport, IMPORT, "results", lambda bad: [VALUE | {"process": bad}]),
    (ResultsImport, IMPORT, "results", lambda bad: [VALUE | {"counter": bad}]),
    (ResultsImport, IMPORT, "results", lambda bad: [VALUE | {"params": {bad: 1}}]),
    (ResultsImport, IMPORT, "results", lambda bad: [VALUE | {"params": {"legs": bad}}]),
    (SubscriptionCreate, MAIL, "counters", lambda bad: [bad]),
    (RegisterRequest, {"name": "perf1"}, "name", lambda bad: bad),
    (RegisterRequest, {"name": "perf1"}, "labels", lambda bad: [bad]),
    (RegisterRequest, {"name": "perf1"}, "fingerprint", lambda bad: {"cpu": bad}),
    (ComponentCreate, {"name": "c"}, "description", lambda bad: bad),
    (ComponentSettings, {}, "description", lambda bad: bad),
    (HostRequest, {"host": "perf1"}, "host", lambda bad: bad),
]
#: CR/LF; C1's NEL (a line break to some readers); RLO (shows what follows reversed); U+2028
UNSEEN = {"a\r\nb": "'\\r' at position 1", "a\x85b": "'\\x85' at position 1"}
UNSEEN |= {"ab\u202ecd": "'\\u202e' at position 2", "a\u2028b": "'\\u2028' at position 1"}


@pytest.mark.parametrize(("model", "body", "field", "put"), CASES)
@pytest.mark.parametrize(("bad", "said"), UNSEEN.items())
def test_unseen_characters_are_refused_naming_them(model, body, field, put, bad, said):
    model.model_validate(body)  # the body is valid without the bad text
    with pytest.raises(ValidationError) as refused:
        model.model_validate(body | {field: put(bad)})
    messages = [error["msg"] for error in refused.value.errors()]
    assert any(f"must not contain {said}" in message for message in messages), messages


def test_text_that_shows_as_itself_is_kept():
    """Spaces and letters of any script pass where a line of text may hold them."""
    kept = RevisionCreate.model_validate(REVISION | {"title": "v1.2 rc1", "sort_key": "Größe 2"})
    assert (kept.title, kept.sort_key) == ("v1.2 rc1", "Größe 2")
    value = VALUE | {"process": "map server", "counter": "rtt p90", "params": {"größe": 1}}
    imported = ResultsImport.model_validate(IMPORT | {"results": [value]})
    assert imported.results[0].process == "map server"
    assert SubscriptionCreate.model_validate(MAIL | {"counters": ["rtt p90"]}).counters
    # format characters that are text: a ZWJ in an emoji, a ZWNJ in a Persian word
    for branch in ("feat/\U0001f469\u200d\U0001f4bb", "\u0645\u06cc\u200c\u0631\u0648\u0645"):
        assert RevisionCreate.model_validate(REVISION | {"branch": branch}).branch == branch


@pytest.mark.parametrize("name", ["compose-../../x", "a\\b/c", "perf 1", "perf-\u00fc1"])
def test_a_host_name_is_one_word_of_one_path_segment(name):
    with pytest.raises(ValidationError):
        RegisterRequest.model_validate({"name": name})


def test_a_number_where_text_is_asked_is_refused_in_words():
    """``"sort_key": NaN`` said "Input should be a valid string"; a whole number is its text."""
    assert RevisionCreate.model_validate(REVISION | {"sort_key": 12}).sort_key == "12"
    for number in (float("nan"), 1.5):
        with pytest.raises(ValidationError) as refused:
            RevisionCreate.model_validate(REVISION | {"sort_key": number})
        said = refused.value.errors()[0]["msg"]
        assert f"must be text or a whole number, not {number!r}" in said, said
    with pytest.raises(ValidationError) as refused:
        SubscriptionCreate.model_validate(MAIL | {"min_effect": float("nan")})
    assert refused.value.errors()[0]["msg"] == "Input should be a finite number"


def test_a_parameter_value_is_text_a_number_or_a_truth_value():
    """``{"legs": NaN}`` was stored and shown as None, nan and NaN on three pages."""
    kept = {"legs": 8, "rate": 2.5, "fast": True, "mode": "größe"}
    imported = ResultsImport.model_validate(IMPORT | {"results": [VALUE | {"params": kept}]})
    assert imported.results[0].params == kept
    for bad, said in [
        (float("nan"), "must be a finite number, not nan"),
        (float("inf"), "must be a finite number, not inf"),
        ([1, 2], "must be text, a number, true or false, not list"),
        (None, "must be text, a number, true or false, not NoneType"),
    ]:
        with pytest.raises(ValidationError) as refused:
            ResultsImport.model_validate(IMPORT | {"results": [VALUE | {"params": {"legs": bad}}]})
        error = refused.value.errors()[0]
        assert said in error["msg"] and error["loc"][-1] == "legs", error


LNT = {"format_version": "2", "machine": {"name": "m1"}, "run": {"llvm_project_revision": "1"}}


@pytest.mark.parametrize(
    ("where", "report"),
    [
        ("tests[0].name", {"tests": [{"name": "a\r\nb", "t": 1}]}),
        ("tests[0] metric", {"tests": [{"name": "a", "t\u202e": 1}]}),
        ("machine.name", {"machine": {"name": "m/1"}}),
        # a NaN name became a host called "nan"; a NaN order was "no order field"
        ("machine.name", {"machine": {"name": float("nan")}}),
        ("run field 'llvm_project_revision'", {"run": {"llvm_project_revision": float("nan")}}),
        ("run field 'llvm_project_revision'", {"run": {"llvm_project_revision": [1]}}),
        # an order read as a Unix time in 2100: it would sort above every later run
        ("run field 'llvm_project_revision'", {"run": {"llvm_project_revision": 4102444800}}),
    ],
)
def test_an_lnt_report_with_unseen_characters_is_refused_naming_where(where, report):
    good = LNT | {"tests": [{"name": "a", "t": 1}]}
    assert parse_lnt(json.dumps(good).encode(), "c").host == "m1"
    with pytest.raises(BadRequest, match=re.escape(f"LNT report: {where} ")):
        parse_lnt(json.dumps(good | report).encode(), "c")


def test_only_an_id_in_the_address_past_any_stored_one_makes_an_unstorable_value_a_404() -> None:
    """A name of digits is a name (a component "12345678901"): a value out of range in its
    request is the body's fault (422), not an address of nothing (404)."""

    def address(**params: str) -> Request:
        return Request({"type": "http", "method": "POST", "path_params": params})

    assert _huge_path_id(address(job_id=str(2**40)))
    assert _huge_path_id(address(id=str(-(2**31))))
    assert _huge_path_id(address(name_or_id=str(2**64)))
    assert not _huge_path_id(address(job_id=str(2**31 - 1)))  # it could be stored
    assert not _huge_path_id(address(name=str(2**40)))  # a component's name of digits
    assert not _huge_path_id(address(title=str(2**40), name="builder"))  # a revision's title


@pytest.mark.parametrize("key", ["1" * 400, int("1" * 400)])
def test_an_over_long_sort_key_is_named_in_characters(key: object) -> None:
    """A trial's 400-digit sort key was refused "at most 200 items after validation"."""
    with pytest.raises(ValidationError, match="at most 200 characters"):
        RevisionCreate(component="c", title="t", sort_key=key, commit="abc1234")
