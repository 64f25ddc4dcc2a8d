"""The browser pages on real Postgres through the real app: the component page's grouped charts,
filters kept in the address, the figure cache, the revision and regression pages, 404 and 400
pages that name what is wrong, and paged lists in the API."""

from __future__ import annotations

import html
import json
import re
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from redline.server.db import session_factory
from redline.server.models import FigureCache
from redline.server.schemas.revisions import RevisionCreate
from redline.server.services.errors import BadRequest, Conflict
from redline.server.services.revisions import create_revision
from redline.server.services.signin import (
    SESSION_COOKIE,
    check_password,
    create_user,
    current,
)
from redline.server.services.tokens import issue_token
from redline.server.services.trend_view import MAX_CHARTS
from sqlalchemy import func, select, text

from tests.support.pages import form_token, history, page_client, sign_in, trend_data
from tests.support.servers import Services

EVIL = '<a href="https://evil.example/phish">x</a>'


@pytest.fixture
def client(services: Services, database_url: str, tmp_path: Path) -> Iterator[TestClient]:
    with page_client(services, database_url, tmp_path) as client:
        yield client


def _admin(client: TestClient) -> dict[str, str]:
    with session_factory(client.app.state.settings.database_url)() as session:
        return {
            "Authorization": f"Bearer {issue_token(session, f'admin-{uuid.uuid4()}', 'admin')[1]}"
        }


def test_component_page_groups_charts_one_line_per_parameter_set(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0, 20.0, 60.0])
    answer = client.get("/components/builder")
    assert answer.status_code == 200, answer.text
    data = trend_data(answer.text)
    titles = [c["title"] for c in data["charts"]]
    assert any(t.endswith("builder.cpu") for t in titles), titles
    assert [r[0] for r in data["revisions"]] == ["r1", "r2", "r3"]  # oldest first
    (cpu,) = [c for c in data["charts"] if c["title"] == "build/steady builder.cpu"]
    lines = [t["name"] for t in cpu["figure"]["data"] if t.get("mode") == "lines+markers"]
    assert lines == ["legs=2", "legs=8"]  # one line per parameter set, each with its band
    assert sum(t.get("fill") == "tonexty" for t in cpu["figure"]["data"]) == 2
    marks = [t for t in cpu["figure"]["data"] if t.get("name", "").startswith("change")]
    assert marks and all(set(t["x"]) == {"r3"} for t in marks), marks
    assert all(isinstance(i, int) for t in marks for i in t["customdata"])
    assert all(len(r) == 3 for r in data["revisions"])  # title, commit, time for the hover


def test_flags_that_do_not_alarm_are_drawn_only_when_asked(client, database_url, tmp_path):
    """A new user read KS's open circles, on most unchanged revisions at one execution each, as
    alarms: a method that charts and does not alarm has its flags drawn only when asked."""
    history(database_url, tmp_path, [20.0, 20.0, 60.0])
    with session_factory(database_url)() as session:  # KS charts, the execution-level alarms
        config = {"methods": ["execution_shift", "ks"], "alarm_methods": ["execution_shift"]}
        session.execute(text("UPDATE detection_config SET config = CAST(:c AS json)"), {
            "c": json.dumps(config)})  # fmt: skip
        session.commit()
    history(database_url, tmp_path, [60.0, 20.0], start=4)  # KS flags r4 and r5, no regression

    def drawn(query: str) -> dict[str, set[str]]:
        data = trend_data(client.get(f"/components/builder{query}").text)
        marks: dict[str, set[str]] = {}
        for chart in data["charts"]:
            for trace in chart["figure"]["data"]:
                if trace.get("name", "").startswith("change"):
                    marks.setdefault(trace["name"], set()).update(trace["x"])
        return marks

    asked = drawn("?flags=1")
    assert {"r4", "r5"} & asked.get("change (flagged, no alarm)", set()), asked
    default = drawn("")
    assert "change (flagged, no alarm)" not in default, default
    # a regression's change is drawn as before, in its regression's state
    assert any("r3" in revisions for revisions in default.values()), default
    assert 'name="flags" value="1" checked' in client.get("/components/builder?flags=on").text


def test_the_trends_say_why_revisions_without_a_verdict_have_no_marks(
    client, database_url, tmp_path
):
    """A trial on a busy host saw charts without a mark and nothing saying why."""
    history(database_url, tmp_path, [20.0])  # one revision: nothing to compare it with
    note = re.search(
        r'<p class="meta" id="unjudged">(.*?)</p>', client.get("/components/builder").text
    )
    assert (
        note
        and "1 of the newest 1 revisions are not judged yet (not enough data: no change can be "
        "marked). The commonest reason, ks: not enough data yet: "
        in note.group(1)
    )
    assert "baseline" in note.group(1)  # the reason, as the revision list says it
    history(database_url, tmp_path, [20.0], start=2)  # judged against r1
    note = re.search(r'id="unjudged">(.*?)</p>', client.get("/components/builder").text)
    assert note and "1 of the newest 2 revisions" in note.group(1), note


def test_filters_are_kept_in_the_address_and_choose_the_charts(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0, 20.0])
    everything = trend_data(client.get("/components/builder").text)["charts"]
    chosen = client.get("/components/builder?counter=cpu&log=1&median=1&revisions=1")
    assert chosen.status_code == 200
    charts = trend_data(chosen.text)["charts"]
    assert 0 < len(charts) < len(everything)
    assert all(c["title"].endswith(".cpu") for c in charts)
    assert all(c["figure"]["layout"]["yaxis"]["type"] == "log" for c in charts)
    assert any("moving median" in t.get("name", "") for c in charts for t in c["figure"]["data"])
    assert [r[0] for r in trend_data(chosen.text)["revisions"]] == ["r2"]  # the newest
    # the form shows the choice made, so the address and the page agree
    assert re.search(r'<option value="cpu" selected>', chosen.text)
    assert 'name="log" value="1" checked' in chosen.text


def test_earlier_history_is_a_link_away(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0, 20.0, 20.0])
    newest = client.get("/components/builder?revisions=2")
    link = re.search(r'id="earlier" href="\?([^"]+)"', newest.text)
    assert link, "a page that does not show the whole history links the earlier part"
    earlier = client.get("/components/builder?" + link.group(1).replace("&amp;", "&"))
    shown = [r[0] for r in trend_data(earlier.text)["revisions"]]
    assert shown == ["r1"], shown


def test_the_chart_data_of_a_longer_history_is_there_for_zoom_and_pan(
    client, database_url, tmp_path
):
    history(database_url, tmp_path, [20.0, 20.0, 20.0, 60.0])
    page = client.get("/components/builder?counter=cpu&revisions=2")
    charts = re.search(r'id="charts" data-source="([^"]+)" data-view="([^"]*)"', page.text)
    assert charts, "the page says where its charts' data comes from"
    source, view = charts.group(1), charts.group(2).replace("&amp;", "&")
    assert source == "/components/builder/trends" and view == "counter=cpu&revisions=2"
    assert 'data-earlier="r3"' in page.text

    answer = client.get(f"{source}?counter=cpu&revisions=4")
    assert answer.status_code == 200 and answer.headers["content-type"] == "application/json"
    body = answer.json()
    assert body["earlier"] is None and body["view"] == "counter=cpu&revisions=4"
    assert [r[0] for r in body["page"]["revisions"]] == ["r1", "r2", "r3", "r4"]
    assert body["page"]["charts"] and all(
        c["title"].endswith(".cpu") for c in body["page"]["charts"]
    )
    assert client.get(f"{source}?revisions=3").json()["earlier"] == "r2"
    # the same view as the page's, from the same cache: what the page shows is a prefix of it
    assert body["page"]["charts"][0]["title"] == trend_data(page.text)["charts"][0]["title"]

    for count in ("5000", "²", "-1"):  # "²" is a digit to str.isdigit, not a number
        bad = client.get(f"{source}?revisions={count}")
        assert bad.status_code == 400 and "revisions" in bad.json()["detail"], bad.text
    keys = [json.loads(c["key"]) for c in body["page"]["charts"]]
    assert len({tuple(k) for k in keys}) == len(keys)  # what the page matches charts by
    assert all(
        k[:2] == [c["case"], c["phase"]] for k, c in zip(keys, body["page"]["charts"], strict=True)
    )
    bad = client.get(f"{source}?revisions=5000")
    assert bad.status_code == 400 and "revisions" in bad.json()["detail"]
    assert client.get(f"{source}?before=nope").status_code == 400
    missing = client.get("/components/nope/trends")
    assert missing.status_code == 404 and "nope" in missing.json()["detail"]


def test_bad_filters_and_unknown_things_are_pages_naming_them(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0])
    bad = client.get("/components/builder?revisions=0")
    assert bad.status_code == 400 and "revisions" in bad.text
    assert client.get("/components/builder?before=nope").status_code == 400
    for switch, value in (("median", "abc"), ("log", "maybe")):  # not silently "off"
        bad = client.get(f"/components/builder?{switch}={value}")
        assert bad.status_code == 400 and f"{switch}: 1 or 0" in bad.text, bad.text
    assert client.get("/components/builder?log=on&median=0").status_code == 200
    # a filter value no series has (a trial read "No results for this view yet")
    for query, said in (
        ("case=nosuch", "case: builder has no case 'nosuch' (it has 'build')"),
        ("param.legs=99", "param.legs: builder's parameter 'legs' is never '99' (it is '2', '8')"),
        ("param.rate=2", "param.rate: builder has no parameter 'rate' (its parameters: legs)"),
    ):
        unknown = client.get(f"/components/builder?{query}")
        assert unknown.status_code == 400 and said in html.unescape(unknown.text), unknown.text
    assert client.get("/components/builder?case=build&param.legs=8").status_code == 200
    nul = client.get("/components/builder?before=%00")  # was a 422 naming a database detail
    assert nul.status_code == 400 and "before: must not contain control" in nul.text, nul.text
    missing = client.get("/components/nope")
    assert missing.status_code == 404 and "nope" in missing.text
    # one side alone is checked too (a trial's ?base=zzz&candidate= answered "Choose two")
    alone = client.get("/components/builder/compare?base=zzz&candidate=")
    assert alone.status_code == 404 and "zzz" in alone.text
    assert client.get("/components/builder/compare?base=r1").status_code == 200
    assert client.get("/components/builder/revisions/r99").status_code == 404
    assert client.get("/regressions/999999").status_code == 404
    assert client.get("/regressions?state=closed").status_code == 400


@pytest.mark.parametrize(
    ("path", "named"),
    [
        ("/executions/abc", "no execution 'abc'"),
        ("/executions/abc/recording", "no execution 'abc'"),
        ("/regressions/1x", "no regression '1x'"),
        ("/detections/-", "no detection '-'"),
        ("/components/builder/models/abc", "no model 'abc'"),
    ],
)
def test_an_address_that_does_not_parse_is_a_page_naming_it_not_json(client, path, named):
    """A trial from outside followed such links and met FastAPI's raw JSON (2026-11-24)."""
    page = client.get(path, headers={"accept": "text/html,application/xhtml+xml"})
    assert page.status_code == 404 and page.headers["content-type"].startswith("text/html")
    assert "<h1>Not found</h1>" in page.text and named in html.unescape(page.text)
    # the API, and a script's fetch of what is not a page (a recording), still get JSON
    for fetched in ("/api/v1/executions/abc", "/executions/abc/recording"):
        api = client.get(fetched)
        assert api.status_code == 422 and api.json()["detail"][0]["loc"][0] == "path"


@pytest.mark.parametrize(
    ("path", "named"),
    [
        ("/executions/abc", "no execution 'abc'"),
        ("/regressions/99999999999999999999999", "/regressions/99999999999999999999999"),
        ("/detections/99999999999999999999999", "an id out of range"),
        ("/components/nosuch", "nosuch"),
    ],
)
def test_a_page_asked_for_without_accepting_html_still_answers_an_error_page(client, path, named):
    """A trial's curl of page addresses met pydantic's 422 and JSON 404s; docs/ui.md promises
    a 404 page naming what does not exist."""
    page = client.get(path)  # curl's Accept: */*
    assert page.status_code == 404 and page.headers["content-type"].startswith("text/html")
    assert "<h1>Not found</h1>" in page.text and named in html.unescape(page.text)


def test_an_id_out_of_range_and_an_unknown_address_are_404_not_json_in_a_page(client):
    """A trial from outside met 422 "cannot be stored" for a GET of /executions/<21 digits>,
    and JSON for an address no page has (2026-11-24)."""
    browser = {"accept": "text/html"}
    huge = client.get("/executions/99999999999999999999", headers=browser)
    assert huge.status_code == 404 and huge.headers["content-type"].startswith("text/html")
    api = client.get("/api/v1/executions/99999999999999999999")
    assert api.status_code == 404 and "out of range" in api.json()["detail"]
    nowhere = client.get("/nonexistent", headers=browser)
    assert nowhere.status_code == 404 and "<h1>Not found</h1>" in nowhere.text
    assert client.get("/api/v1/nonexistent").json() == {"detail": "Not Found"}


def test_a_form_posted_to_a_page_address_that_does_not_parse_is_a_page(client):
    page = client.post("/settings/tokens/abc/revoke", headers={"accept": "text/html"})
    assert page.status_code == 404 and "no token 'abc'" in html.unescape(page.text)


def test_a_parameters_numeric_values_are_offered_in_numeric_order(client):
    """A trial's filter offered "100 150 50"; text values follow the numbers, as text."""
    admin = _admin(client)
    client.post("/api/v1/components", json={"name": "sizes"}, headers=admin)
    values = [100, 150, 50, 2.5, -1, "large", "huge"]
    body = {
        "component": "sizes",
        "revision": "r1",
        "sort_key": "1",
        "results": [
            {"case": "c", "params": {"n": n}, "counter": "cpu", "values": [1.0]} for n in values
        ],
    }
    answer = client.post("/api/v1/import/results", json=body, headers=admin)
    assert answer.status_code == 201, answer.text
    page = client.get("/components/sizes").text
    offered = re.search(r'<select name="param.n">(.*?)</select>', page, re.S).group(1)
    shown = re.findall(r'<option value="([^"]*)"', offered)
    assert shown == ["", "-1", "2.5", "50", "100", "150", "huge", "large"], shown


def test_a_view_of_more_charts_than_a_page_draws_draws_the_first_and_says_how_to_see_the_rest(
    client,
):
    """A trial imported 20,000 series: the unfiltered page was 30 MB and took 5 s."""
    admin = _admin(client)
    client.post("/api/v1/components", json={"name": "wide"}, headers=admin)
    counters, sets = MAX_CHARTS + 20, 6
    body = {
        "component": "wide",
        "revision": "r1",
        "sort_key": "1",
        "results": [
            {"case": "c", "params": {"n": n}, "counter": f"k{k:03d}", "values": [1.0]}
            for k in range(counters)
            for n in range(sets)
        ],
    }
    assert client.post("/api/v1/import/results", json=body, headers=admin).status_code == 201
    page = client.get("/components/wide").text
    where = re.search(r'<p class="meta" id="where">(.*?)</p>', page).group(1)
    assert where == "imported results only: no repository for the hosts to measure", where
    titles = [chart["title"] for chart in trend_data(page)["charts"]]
    assert len(titles) == MAX_CHARTS and titles[-1].endswith(f"k{MAX_CHARTS - 1:03d}"), titles
    note = html.unescape(re.search(r'<p class="meta" id="cut">(.*?)</p>', page).group(1))
    assert note.startswith(
        f"This view holds {counters * sets} series in {counters} charts; the page draws the "
        f"first {MAX_CHARTS} charts ({MAX_CHARTS * sets} series)."
    ), note
    assert (
        json.loads(client.get("/components/wide/trends").text)["page"]["charts"][-1]["title"]
        == titles[-1]
    )  # the longer history zoom loads is the same cut
    last = f"k{counters - 1:03d}"
    page = client.get(f"/components/wide?counter={last}").text  # as the note says: filter
    assert [c["title"] for c in trend_data(page)["charts"]] == [f"c/main benchmark.{last}"]
    assert 'id="cut"' not in page


def test_the_page_is_served_from_the_cache_until_the_data_changes(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0, 20.0])
    first = client.get("/components/builder").text
    with session_factory(database_url)() as session:
        (row,) = session.scalars(select(FigureCache)).all()
        version = row.version
    assert trend_data(client.get("/components/builder").text) == trend_data(first)
    history(database_url, tmp_path, [20.0], start=3)  # a new revision: a new data version
    shown = [r[0] for r in trend_data(client.get("/components/builder").text)["revisions"]]
    assert "r3" in shown
    with session_factory(database_url)() as session:
        assert session.scalar(select(func.count()).select_from(FigureCache)) == 1
        assert session.scalar(select(FigureCache.version)) != version


def test_untrusted_names_are_text_in_the_page_and_in_the_charts(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0], case=EVIL)
    page = client.get("/components/builder").text
    assert EVIL not in page and '<a href="https://evil' not in page
    titles = [c["figure"]["layout"]["title"]["text"] for c in trend_data(page)["charts"]]
    assert any("&lt;a href" in t for t in titles), titles  # plotly shows the markup as text


def test_revision_and_regression_pages_link_each_other(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0, 20.0, 200.0])
    regressions = client.get("/api/v1/components/builder/regressions").json()
    assert regressions, "the tripled CPU makes a regression"
    number = regressions[0]["id"]
    component = client.get("/components/builder").text
    assert f'href="/regressions/{number}"' in component
    page = client.get(f"/regressions/{number}")
    assert page.status_code == 200 and f"Regression #{number}" in page.text
    # what each triage state does, said to everyone (a trial asked how "acknowledged" and
    # "confirmed" differ, and which of them stop the alerts)
    states = re.search(r'<details id="triage-states">(.*?)</details>', page.text, re.S).group(1)
    assert "<dt>confirm (confirmed)</dt><dd>a person checked that it is real" in states
    assert states.count("Closed: no more alerts") == 3 and states.count("Still open") == 2
    bad = regressions[0]["bad_revision"]
    assert f'href="/components/builder/revisions/{bad}"' in page.text
    revision = client.get(f"/components/builder/revisions/{bad}")
    assert revision.status_code == 200
    assert f'href="/regressions/{number}"' in revision.text and "builder.cpu" in revision.text
    # which method fails CI, said above the verdicts (the history's config: KS alone)
    said = re.search(r'<p class="meta" id="alarming">(.*?)</p>', revision.text).group(1)
    assert said.startswith("A change for the worse found by ks or count_rate is a regression")
    listed = client.get("/regressions?component=builder&confirmation=suspected")
    assert listed.status_code == 200
    # each with its largest change (a trial found the size only on the regression's own page)
    largest = regressions[0]["largest"]
    assert re.fullmatch(r".*builder cpu.* \+\d+\.\d % at r3", largest), largest
    assert f"<td>{html.escape(largest)}</td>" in listed.text
    detail = client.get(f"/api/v1/components/builder/regressions/{number}").json()
    assert detail["largest"] == largest


def test_home_page_lists_components_hosts_and_the_queue(client, database_url, tmp_path):
    from redline.server.schemas.jobs import RegisterRequest
    from redline.server.services.jobs import register_host

    history(database_url, tmp_path, [20.0, 20.0])
    with session_factory(database_url)() as session:
        machine = {"cpu_model": "Xeon E5", "load_1m": "3.75", "load_5m": "2.10"}
        register_host(session, RegisterRequest(name="perf-home", fingerprint=machine))
        session.commit()
    page = client.get("/")
    assert page.status_code == 200
    assert 'href="/components/builder"' in page.text and "Job queue" in page.text
    assert '<svg class="spark"' in page.text  # the headline series' sparkline
    # the machine as it registered, but not its load then, which read as its load now (a trial)
    row = next(r for r in page.text.split("<tr>") if "<td>perf-home</td>" in r)
    assert "cpu_model=Xeon E5" in row and "load_" not in row and "3.75" not in row


@pytest.mark.parametrize(
    "path",
    [
        "/api/v1/components/builder/changes",
        "/api/v1/components/builder/detections",
        "/api/v1/components/builder/regressions",
        "/api/v1/components/builder/executions",
    ],
)
def test_lists_that_grow_with_history_are_paged(client, database_url, tmp_path, path):
    history(database_url, tmp_path, [20.0, 20.0, 200.0, 200.0, 800.0])
    everything = client.get(path).json()
    assert len(everything) >= 2, path
    seen, cursor = [], None
    while True:
        query = "?limit=1" + (f"&cursor={cursor}" if cursor else "")
        page = client.get(path + query)
        assert page.status_code == 200, page.text
        seen += page.json()
        cursor = page.headers.get("x-next-cursor")
        if cursor is None:
            break
    assert seen == everything
    bad = client.get(path + "?limit=1&cursor=bm9wZQ")
    assert bad.status_code == 400 and "cursor" in bad.json()["detail"]


def _regression(client: TestClient, database_url: str, tmp_path: Path) -> int:
    history(database_url, tmp_path, [20.0, 20.0, 200.0])
    return client.get("/api/v1/components/builder/regressions").json()[0]["id"]


def _state(client: TestClient, number: int) -> str:
    return client.get(f"/api/v1/components/builder/regressions/{number}").json()["state"]


def test_triage_in_the_page_needs_a_sign_in_and_the_form_token(client, database_url, tmp_path):
    number = _regression(client, database_url, tmp_path)
    with session_factory(database_url)() as session:
        create_user(session, "ada", "correct horse battery", "triage")
        create_user(session, "reader", "correct horse battery", "read")
        with pytest.raises(BadRequest, match="'agent' is for a host's token"):  # a trial made one
            create_user(session, "eve", "correct horse battery", "agent")
        with pytest.raises(BadRequest) as unknown:  # offers a person's scopes, not a host's
            create_user(session, "eve", "correct horse battery", "root")
        assert str(unknown.value.detail).endswith("known: admin, ci, read, triage")
    triage = f"/regressions/{number}/triage"
    refused = client.post(triage, data={"state": "confirmed", "csrf": "x"})
    assert refused.status_code == 403 and "sign in" in refused.text
    assert "Sign in</a> to triage" in client.get(f"/regressions/{number}").text
    wrong = sign_in(client, {"name": "ada", "password": "wrong password!!"})
    assert wrong.status_code == 403 and "wrong name or password" in wrong.text
    answer = sign_in(
        client,
        {"name": "ada", "password": "correct horse battery", "next": "//evil.example/"},
        follow_redirects=False,
    )
    assert answer.status_code == 303 and answer.headers["location"] == "/"  # never off-site
    cookie = answer.headers["set-cookie"].lower()
    assert "httponly" in cookie and "samesite=strict" in cookie
    page = client.get(f"/regressions/{number}").text
    assert 'id="triage"' in page
    forged = client.post(triage, data={"state": "confirmed", "csrf": "forged"})
    assert forged.status_code == 403 and "token" in forged.text
    assert _state(client, number) == "new"
    done = client.post(
        triage,
        data={"state": "confirmed", "comment": "bisected", "csrf": form_token(page)},
        follow_redirects=False,
    )
    assert done.status_code == 303, done.text
    detail = client.get(f"/api/v1/components/builder/regressions/{number}").json()
    assert detail["state"] == "confirmed"
    assert [(e["who"], e["to_state"], e["comment"]) for e in detail["history"]] == [
        ("ada", "confirmed", "bisected")
    ]
    client.post("/signout", data={"csrf": form_token(client.get("/").text)})
    assert client.post(triage, data={"state": "fixed", "csrf": form_token(page)}).status_code == 403
    sign_in(client, {"name": "reader", "password": "correct horse battery"})
    reader = client.post(
        triage,
        data={"state": "fixed", "csrf": form_token(client.get(f"/regressions/{number}").text)},
    )
    assert reader.status_code == 403 and "lacks the &#39;triage&#39; scope" in reader.text
    assert _state(client, number) == "confirmed"


STATES = ("new", "acknowledged", "confirmed", "false_positive", "fixed", "ignored")


def test_a_triage_to_no_state_names_the_field_and_the_states_not_pydantic(
    client, database_url, tmp_path
):
    """A trial's page read pydantic's own text, ending "For further information visit
    https://errors.pydantic.dev/..."."""
    number = _regression(client, database_url, tmp_path)
    with session_factory(database_url)() as session:
        create_user(session, "ada", "correct horse battery", "triage")
    sign_in(client, {"name": "ada", "password": "correct horse battery"})
    csrf = form_token(client.get(f"/regressions/{number}").text)
    for given, field in (({"state": "closed"}, "state"), ({"comment": "x" * 10_001}, "comment")):
        data = {"state": "confirmed", "csrf": csrf, **given}
        answer = client.post(f"/regressions/{number}/triage", data=data)
        said = html.unescape(re.search(r'class="problem">(.*?)</p>', answer.text, re.S).group(1))
        assert answer.status_code == 400 and said.startswith(f"triage: {field}: "), said
        assert "pydantic" not in said and "validation error" not in said and "\n" not in said
        if field == "state":  # the value given, and every one allowed
            assert "'closed'" in said and all(f"'{s}'" in said for s in STATES), said
        assert f'<a href="/regressions/{number}">Back to regression #{number}</a>' in answer.text
    none = client.post(f"/regressions/{number}/triage", data={"csrf": csrf, "comment": "hm"})
    said = html.unescape(re.search(r'class="problem">(.*?)</p>', none.text, re.S).group(1))
    assert none.status_code == 400 and said.startswith("triage: choose the state to set"), said
    assert _state(client, number) == "new"


def test_a_form_value_no_text_holds_is_a_page_naming_it_never_a_500(client, database_url, tmp_path):
    """A review (2026-12-06): a triage comment holding a NUL reached the database, whose refusal
    rolled the session back, and the error page, reading who was signed in from the expired
    session row, answered 500; so did a token name past 200 characters from the settings form."""
    number = _regression(client, database_url, tmp_path)
    with session_factory(database_url)() as session:
        create_user(session, "ada", "correct horse battery", "triage,admin")
    sign_in(client, {"name": "ada", "password": "correct horse battery"})
    csrf = form_token(client.get(f"/regressions/{number}").text)
    form = {"state": "confirmed", "comment": "a\x00b", "csrf": csrf}
    answer = client.post(f"/regressions/{number}/triage", data=form)
    said = html.unescape(re.search(r'class="problem">(.*?)</p>', answer.text, re.S).group(1))
    assert answer.status_code == 422 and "'comment' holds a NUL" in said, said
    assert _state(client, number) == "new"
    long = client.post("/settings/tokens", data={"name": "n" * 195, "scopes": "ci", "csrf": csrf})
    assert long.status_code == 400 and "at most 194 characters" in long.text
    # the longest name signs in: its session is "token <name>", 200 characters
    made = client.post("/settings/tokens", data={"name": "n" * 194, "scopes": "read", "csrf": csrf})
    secret = re.search(r'<code id="new-token">([^<]+)</code>', made.text).group(1)
    client.post("/signout", data={"csrf": csrf})
    assert sign_in(client, {"token": secret}).status_code in (200, 303)
    assert "token " + "n" * 194 in client.get("/").text
    client.post("/signout", data={"csrf": form_token(client.get("/").text)})
    sign_in(client, {"name": "ada", "password": "correct horse battery"})
    # what the error page reads of the session survives the request's session rolled back and
    # closed, as a failed write leaves it before the error page is drawn
    with session_factory(database_url)() as session:
        row = current(session, client.cookies.get(SESSION_COOKIE))
        assert row is not None
        session.rollback()
        session.close()
        assert (row.who, row.scopes, len(row.csrf)) == ("ada", ["admin", "triage"], len(csrf))


def test_a_pasted_token_signs_in_with_its_own_scopes_only(client, database_url, tmp_path):
    number = _regression(client, database_url, tmp_path)
    with session_factory(database_url)() as session:
        _, agent = issue_token(session, "perf-host", "agent", "perf-host")
        _, ci = issue_token(session, "gitlab", "ci")
        _, triage = issue_token(session, "on-call", "triage")
    refused = sign_in(client, {"token": agent})
    assert refused.status_code == 403 and "hosts" in refused.text
    assert sign_in(client, {"token": "rl_nope"}).status_code == 403
    sign_in(client, {"token": ci})  # a pipeline's token reads, and triages nothing
    page = client.get(f"/regressions/{number}").text
    assert 'id="triage"' not in page and "Triage needs the <code>triage</code> scope" in page
    pipeline = client.post(
        f"/regressions/{number}/triage", data={"state": "ignored", "csrf": form_token(page)}
    )
    assert pipeline.status_code == 403 and _state(client, number) == "new"
    # signing out needs the session's form token too: another site's form cannot end it
    # (a trial's forged sign-out dropped the cookie and left the session live)
    kept = client.cookies.get(SESSION_COOKIE)
    for forged in ({}, {"csrf": "x" * 32}):
        refused = client.post("/signout", data=forged, follow_redirects=False)
        assert refused.status_code == 403 and "form&#39;s token" in refused.text, refused.text[:300]
        assert SESSION_COOKIE not in refused.headers.get("set-cookie", "")
    assert "Sign out</button>" in client.get(f"/regressions/{number}").text  # still in
    out = client.post("/signout", data={"csrf": form_token(page)}, follow_redirects=False)
    assert out.status_code == 303 and SESSION_COOKIE in out.headers["set-cookie"]
    client.cookies.set(SESSION_COOKIE, kept)  # the old cookie opens nothing once signed out
    assert "Sign out</button>" not in client.get(f"/regressions/{number}").text
    client.cookies.clear()
    sign_in(client, {"token": triage})
    page = client.get(f"/regressions/{number}").text
    done = client.post(
        f"/regressions/{number}/triage", data={"state": "acknowledged", "csrf": form_token(page)}
    )
    assert done.status_code == 200 and _state(client, number) == "acknowledged"
    detail = client.get(f"/api/v1/components/builder/regressions/{number}").json()
    assert detail["history"][0]["who"] == "token on-call"


def test_a_page_offers_triage_only_to_whom_may_triage(client, database_url, tmp_path):
    """A trial signed in with a read token was shown the triage form; its save answered 403."""
    number = _regression(client, database_url, tmp_path)
    with session_factory(database_url)() as session:
        _, read = issue_token(session, "reader", "read")
    sign_in(client, {"token": read})
    page = client.get(f"/regressions/{number}").text
    assert 'id="triage"' not in page and 'name="state"' not in page
    assert "Triage needs the <code>triage</code> scope; token reader has read." in page


def test_passwords_are_stored_as_scrypt_hashes_and_short_ones_refused(database_url):
    with session_factory(database_url)() as session:
        user = create_user(session, "grace", "a long enough secret", "admin")
        assert user.password_hash.startswith("scrypt$") and "secret" not in user.password_hash
        assert check_password("a long enough secret", user.password_hash)
        assert not check_password("a long enough secreT", user.password_hash)
        with pytest.raises(BadRequest, match="12 characters"):
            create_user(session, "short", "tiny", "ci")
        with pytest.raises(Conflict):
            create_user(session, "grace", "another long secret", "ci")


def test_why_flagged_shows_what_was_compared(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0, 20.0, 20.0, 200.0])
    (regression, *_) = client.get("/api/v1/components/builder/regressions").json()
    detail = client.get(f"/api/v1/components/builder/regressions/{regression['id']}").json()
    flagged = next(d for d in detail["flagged"] if d["series"]["counter"] == "cpu")
    assert f'href="/detections/{flagged["id"]}"' in client.get(f"/regressions/{detail['id']}").text
    page = client.get(f"/detections/{flagged['id']}")
    assert page.status_code == 200, page.text
    assert flagged["method"] in page.text
    match = re.search(r'<script type="application/json" id="figure-data">(.*?)</script>', page.text)
    levels, distributions = json.loads(match.group(1))
    sides = {t["name"]: t for t in levels["data"]}
    assert sides["candidate executions"]["x"] == ["r4"]
    pooled = sides["baseline executions"]["x"]  # the baseline as the detection pooled it
    assert pooled[-1] == "r3" and set(pooled) <= {"r1", "r2", "r3"}
    assert min(sides["candidate executions"]["y"]) > 5 * max(sides["baseline executions"]["y"])
    assert "largest gap 1.00" in distributions["layout"]["title"]["text"]  # apart entirely
    # the method's own rule, not one rule for all (KS's score is D: it needs no "1 or more")
    assert "needs 1 or more" not in page.text
    assert flagged["method"] == "ks" and "the score is D (0..1)" in page.text
    assert "left out" not in page.text
    # a run measured while the host was busy is counted apart, as detection left it out (a
    # trial read "1 of 3 executions left out" beside "candidate: 3 execution(s)")
    with session_factory(database_url)() as session:
        session.execute(
            text(
                "UPDATE summary SET disturbed = true WHERE series_id = :series AND execution_id = "
                "(SELECT min(id) FROM execution WHERE revision_id = "
                "(SELECT id FROM revision WHERE title = 'r4'))"
            ),
            {"series": flagged["series"]["id"]},
        )
        session.commit()
    page = client.get(f"/detections/{flagged['id']}")
    counts = re.search(r"<tr><th>baseline</th><td>(.*?)</td>", page.text, re.S).group(1)
    assert counts == "r3 (1 execution(s)); candidate: 1 execution(s), 1 left out: the host was busy"
    assert client.get("/detections/999999").status_code == 404
    # a verdict with no baseline (the first revision's) has its page too: the API lists it
    # (a trial got a 500 for each of those)
    first = client.get("/api/v1/components/builder/detections?revision=r1").json()
    assert first and all(d["verdict"] == "not enough data" for d in first)
    page = client.get(f"/detections/{first[0]['id']}")
    assert page.status_code == 200 and "missing baseline" in page.text, page.text[-500:]


def test_why_flagged_shows_the_thresholds_the_verdict_was_judged_by(client, database_url, tmp_path):
    """A configuration saved without re-analysis leaves the old verdicts as they were judged:
    their page shows the thresholds that judged them, not the new ones (it read the current
    configuration); a verdict judged before they were kept says it shows the current ones."""
    history(database_url, tmp_path, [20.0, 20.0, 20.0, 200.0])
    flagged = next(
        d
        for d in client.get("/api/v1/components/builder/detections?revision=r4").json()
        if d["flagged"] and d["series"]["counter"] == "cpu"
    )
    saved = client.patch(
        "/api/v1/components/builder/detection-config",
        json={"thresholds": {"ks": {"alpha": 0.0001}}, "reanalyze": False},
        headers=_admin(client),
    )
    assert saved.status_code == 200, saved.text
    assert saved.json()["thresholds"]["ks"]["alpha"] == 0.0001
    row = re.compile(r"<tr><th>thresholds</th><td>(.*?)</td></tr>", re.S)
    shown = row.search(client.get(f"/detections/{flagged['id']}").text).group(1)
    assert "alpha = 0.01," in shown and "0.0001" not in shown, shown
    assert 'id="thresholds-now"' not in shown
    with session_factory(database_url)() as session:  # as stored before 0030
        session.execute(
            text("UPDATE detection SET config_id = NULL WHERE id = :id"), {"id": flagged["id"]}
        )
        session.commit()
    shown = row.search(client.get(f"/detections/{flagged['id']}").text).group(1)
    assert "alpha = 0.0001," in shown and 'id="thresholds-now"' in shown, shown


def test_execution_page_has_raw_counters_parameters_the_log_and_the_recording(
    client, database_url, tmp_path
):
    history(database_url, tmp_path, [20.0])
    (job,) = client.get("/api/v1/components/builder/revisions/r1").json()["jobs"]
    number = job["execution"]["id"]
    assert f'href="/executions/{number}"' in client.get("/components/builder/revisions/r1").text
    page = client.get(f"/executions/{number}")
    assert page.status_code == 200, page.text
    match = re.search(r'<script type="application/json" id="figure-data">(.*?)</script>', page.text)
    charts = {c["layout"]["title"]["text"]: c for c in json.loads(match.group(1))}
    raw = charts["builder.cpu"]
    assert len(raw["layout"]["shapes"]) == 2  # the two parameter sets' phases, shaded
    assert any("legs=8" in note["text"] for note in raw["layout"]["annotations"])
    against = charts["builder.cpu against legs"]["data"][0]
    assert against["x"] == [2.0, 8.0] and against["y"][1] > 3 * against["y"][0]
    # the component's output, as text: its markup is shown, never run
    assert "<summary>builder (" in page.text and "builder ready" in page.text
    assert "&lt;script&gt;alert(&#39;from the log&#39;)&lt;/script&gt;" in page.text
    assert "<script>alert(" not in page.text
    recording = client.get(f"/executions/{number}/recording")
    assert recording.status_code == 200 and recording.content.startswith(b"\x89MCAP")
    assert client.get("/executions/999999").status_code == 404
    assert client.get("/executions/999999/recording").status_code == 404


def test_compare_page_tables_and_charts_any_two_revisions(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0, 20.0, 200.0])
    page = client.get("/components/builder/compare?base=r1&candidate=r3")
    assert page.status_code == 200, page.text
    assert '<option value="r1" selected>' in page.text  # the choice stays in the form
    match = re.search(r'<script type="application/json" id="figure-data">(.*?)</script>', page.text)
    (chart,) = json.loads(match.group(1))
    changes = dict(zip(chart["data"][0]["y"], chart["data"][0]["x"], strict=True))
    assert changes["build/steady[legs=2] builder.cpu"] > 500  # % : ten times the CPU
    assert client.get("/components/builder/compare").status_code == 200  # choose in the page
    missing = client.get("/components/builder/compare?base=r1&candidate=nope")
    assert missing.status_code == 404 and "nope" in missing.text


def test_settings_pages_are_for_administrators_and_change_what_the_api_does(
    client, database_url, tmp_path
):
    history(database_url, tmp_path, [20.0])
    with session_factory(database_url)() as session:
        create_user(session, "root", "correct horse battery", "admin")
        create_user(session, "ada", "correct horse battery", "ci")
    assert client.get("/settings").status_code == 403  # not signed in
    sign_in(client, {"name": "ada", "password": "correct horse battery"})
    refused = client.get("/settings")
    assert refused.status_code == 403 and "admin" in refused.text
    client.post("/signout", data={"csrf": form_token(client.get("/").text)})
    sign_in(client, {"name": "root", "password": "correct horse battery"})
    page = client.get("/settings")
    assert page.status_code == 200 and 'href="/settings/components/builder"' in page.text
    csrf = form_token(page.text)
    assert client.post("/settings/tokens", data={"name": "x", "scopes": "ci"}).status_code == 403
    made = client.post("/settings/tokens", data={"name": "gitlab", "scopes": "ci", "csrf": csrf})
    secret = re.search(r'<code id="new-token">([^<]+)</code>', made.text).group(1)
    assert client.get("/settings").text.count(secret) == 0  # shown once, never again
    headers = {"Authorization": f"Bearer {secret}"}
    assert client.post("/api/v1/revisions", headers=headers, json={}).status_code == 422  # live
    # an agent token's labels, comma-separated in the form as on the command line
    agent = {"name": "perf-9", "scopes": "agent", "host": "perf-9", "labels": "x86, quiet"}
    assert client.post("/settings/tokens", data={**agent, "csrf": csrf}).status_code == 200
    assert "<td>perf-9</td><td>quiet, x86</td>" in client.get("/settings").text
    form = client.get("/settings/components/builder").text
    bad = client.post("/settings/components/builder", data={"csrf": csrf, "config": "{not json"})
    assert bad.status_code == 400 and "not valid JSON" in bad.text
    # an audit's: nested 2,000 deep it was a 500, where the API's body is a 422 naming it
    deep = client.post("/settings/components/builder", data={"csrf": csrf, "config": "[" * 2000})
    assert deep.status_code == 400 and "nested deeper than" in deep.text, deep.text[-300:]
    unknown = client.post(
        "/settings/components/builder", data={"csrf": csrf, "config": '{"confirm_pairs": 99}'}
    )
    assert unknown.status_code == 400 and "confirm_pairs" in unknown.text
    typo = client.post(
        "/settings/components/builder", data={"csrf": csrf, "config": '{"nonsense_key": 1}'}
    )
    assert typo.status_code == 400 and "nonsense_key" in typo.text
    # the form's JSON is checked as the API's is: a NUL in a pinned title, stored, made every
    # re-analysis fail in the database (a trial, 2026-11-28)
    before = client.get("/api/v1/components/builder/detection-config").json()
    for config in [
        '{"baseline": "pinned", "pinned": "r1\\u0000"}',
        '{"context_counters": ["cpu\\nuser"]}',
        '{"context_counters": ["cpu\\u202euser"]}',
    ]:
        refused = client.post("/settings/components/builder", data={"csrf": csrf, "config": config})
        assert refused.status_code == 400, (config, refused.text)
        assert ("pinned" in refused.text) != ("context_counters" in refused.text), refused.text
    assert client.get("/api/v1/components/builder/detection-config").json() == before
    nan = client.post("/settings/components/builder", data={"csrf": csrf, "executions": "NaN"})
    said = html.unescape(nan.text)
    assert nan.status_code == 400 and "executions: must be a whole number, not 'NaN'" in said, said
    # a value the service refuses (a repository no performance host fetches from): a page
    outside = client.post(
        "/settings/components/builder",
        data={"csrf": csrf, "repo": "ftp://example.org/x.git"},
        headers={"accept": "text/html"},
    )
    assert outside.status_code == 422 and "ftp" in outside.text, outside.text
    assert outside.headers["content-type"].startswith("text/html"), outside.text
    assert "<h1>Bad request</h1>" in outside.text
    saved = client.post(
        "/settings/components/builder",
        data={
            "csrf": csrf,
            "config": '{"confirm_pairs": 2, "reanalyze": false}',
            "executions": "3",
        },
        follow_redirects=False,
    )
    assert saved.status_code == 303, saved.text
    assert client.get("/api/v1/components/builder/detection-config").json()["confirm_pairs"] == 2
    assert client.get("/api/v1/components/builder").json()["executions"] == 3
    assert "builder" in form


def test_the_component_settings_page_subscribes_lists_and_deletes_alerts(
    client, database_url, tmp_path
):
    history(database_url, tmp_path, [20.0])
    with session_factory(database_url)() as session:
        create_user(session, "root", "correct horse battery", "admin")
    sign_in(client, {"name": "root", "password": "correct horse battery"})
    page = client.get("/settings/components/builder")
    assert "No one is subscribed yet." in page.text
    csrf = form_token(page.text)
    path = "/settings/components/builder/subscriptions"
    unsigned = client.post(path, data={"kind": "email", "address": "a@robots.example"})
    assert unsigned.status_code == 403  # no form token
    bad = client.post(path, data={"csrf": csrf, "kind": "webhook", "url": "ftp://x.example"})
    assert bad.status_code == 400 and "http:// or https://" in bad.text
    made = client.post(
        path,
        data={
            "csrf": csrf,
            "kind": "webhook",
            "url": "https://hooks.example/r",
            "secret": "do-not-show",
            "counters": "cpu, rss",
            "min_effect": "5",
            "direction": "any",
        },
        follow_redirects=False,
    )
    assert made.status_code == 303, made.text
    page = client.get("/settings/components/builder").text
    assert "https://hooks.example/r (signed)" in page and "do-not-show" not in page
    assert "any of cpu, rss, at least 5 %, when flagged" in page
    (stored,) = _subscriptions(database_url)
    assert (stored.counters, stored.min_effect, stored.confirmed_only) == (
        ["cpu", "rss"],
        0.05,
        False,
    )
    gone = client.post(f"{path}/{stored.id}/delete", data={"csrf": csrf}, follow_redirects=False)
    assert gone.status_code == 303
    assert "No one is subscribed yet." in client.get("/settings/components/builder").text


def _subscriptions(database_url: str) -> list:
    from redline.server.models import Subscription
    from sqlalchemy import select

    with session_factory(database_url)() as session:
        return list(session.scalars(select(Subscription)))


def test_an_admin_deletes_a_revision_nothing_was_measured_of_from_its_page(
    client, database_url, tmp_path
):
    """A new-user trial's commit reported by mistake stayed "failed" on the home page for good.
    Its page offers an admin to delete it; a measured revision's page offers nothing."""
    history(database_url, tmp_path, [20.0])
    with session_factory(database_url)() as session:
        create_user(session, "ada", "correct horse battery", "admin")
        create_user(session, "reader", "correct horse battery", "read")
    with session_factory(database_url)() as session:  # as CI reports it
        create_revision(
            session,
            RevisionCreate(component="builder", title="typo", sort_key="9", commit="deadbeef"),
        )
    sign_in(client, {"name": "reader", "password": "correct horse battery"})
    assert 'id="delete-revision"' not in client.get("/components/builder/revisions/typo").text
    client.post("/signout", data={"csrf": form_token(client.get("/").text)})
    sign_in(client, {"name": "ada", "password": "correct horse battery"})
    assert 'id="delete-revision"' not in client.get("/components/builder/revisions/r1").text
    page = client.get("/components/builder/revisions/typo").text
    assert 'id="delete-revision"' in page
    action = "/components/builder/revisions/typo/delete"
    forged = client.post(action, data={"csrf": "not-the-token"})  # another site's form
    assert forged.status_code == 403
    done = client.post(action, data={"csrf": form_token(page)}, follow_redirects=False)
    assert done.status_code == 303 and done.headers["location"] == "/components/builder"
    assert client.get("/components/builder/revisions/typo").status_code == 404
    kept = client.post(
        "/components/builder/revisions/r1/delete",
        data={"csrf": form_token(client.get("/components/builder/revisions/r1").text)},
    )
    assert kept.status_code == 409 and "execution(s) stored" in kept.text
