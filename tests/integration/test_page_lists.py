"""The lists and tables of the pages through the real app on real Postgres: the executions
(API and pages), the trends' host filter, the regressions' method filter and pages, the revision
page's values, durations and disturbed phases, compare's verdicts and ranges, and the sign-in
form's own token."""

from __future__ import annotations

import html
import json
import re
from collections.abc import Iterator
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient
from redline.detect.registry import DETECTORS, TITLES
from redline.recording.format import canonical_params
from redline.server.db import session_factory
from redline.server.models import (
    Execution,
    FigureCache,
    Host,
    Job,
    Regression,
    Revision,
    Series,
    utcnow,
)
from redline.server.routes import regression_pages, web
from redline.server.services import compare
from redline.server.services.signin import SESSION_COOKIE, create_user
from redline.server.storage import DISTURBED, samples_path
from sqlalchemy import select, update

from tests.support.pages import history, page_client, sign_in, trend_data
from tests.support.servers import Services

PASSWORD = "correct horse battery"
API = "/api/v1/components/builder"


@pytest.fixture
def client(services: Services, database_url: str, tmp_path: Path) -> Iterator[TestClient]:
    with page_client(services, database_url, tmp_path) as client:
        yield client


def _executions_of(database_url: str, title: str) -> list[Execution]:
    with session_factory(database_url)() as session:
        return list(
            session.scalars(
                select(Execution)
                .join(Revision)
                .where(Revision.title == title)
                .order_by(Execution.id)
            )
        )


def _ran_on(database_url: str, title: str, host: str) -> None:
    """The revision's jobs ran on ``host`` (made if new)."""
    with session_factory(database_url)() as session:
        found = session.scalar(select(Host).where(Host.name == host)) or Host(name=host)
        session.add(found)
        session.flush()
        ids = select(Revision.id).where(Revision.title == title).scalar_subquery()
        session.execute(update(Job).where(Job.revision_id == ids).values(host_id=found.id))
        session.commit()


def _run_took(database_url: str, title: str, seconds: str) -> None:
    """The revision's runs say they started at 10:00:00 and ended ``seconds`` later."""
    meta = {"redline.run": {"started_at": "2026-11-20T10:00:00.000+00:00",
                            "ended_at": f"2026-11-20T10:00:{seconds}+00:00"}}  # fmt: skip
    with session_factory(database_url)() as session:
        ids = select(Revision.id).where(Revision.title == title).scalar_subquery()
        session.execute(update(Execution).where(Execution.revision_id == ids).values(meta=meta))
        session.commit()


def test_executions_are_listed_filtered_and_linked_by_their_pages(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0, 20.0, 20.0])
    _ran_on(database_url, "r2", "perf-a")
    _run_took(database_url, "r2", "12.500")
    (r2,) = _executions_of(database_url, "r2")
    listed = client.get(f"{API}/executions").json()
    assert [e["revision"] for e in listed] == ["r3", "r2", "r1"]  # newest revision first
    assert listed[1]["id"] == r2.id and listed[1]["host"] == "perf-a"
    assert listed[1]["duration_s"] == 12.5 and listed[0]["duration_s"] is None
    assert [e["id"] for e in client.get(f"{API}/executions?host=perf-a").json()] == [r2.id]
    assert [e["id"] for e in client.get(f"{API}/executions?revision=r2").json()] == [r2.id]
    assert len(client.get(f"{API}/executions?state=done").json()) == 3
    assert client.get(f"{API}/executions?state=queued").json() == []
    assert client.get(f"{API}/executions?state=closed").status_code == 422
    for query, named in (("host=nope", "no performance host 'nope'"), ("revision=r9", "r9")):
        missing = client.get(f"{API}/executions?{query}")
        assert missing.status_code == 404 and named in missing.json()["detail"], missing.text

    page = client.get("/components/builder").text
    section = page[page.index("<h2>Executions</h2>") :]
    assert all(f'href="/executions/{e["id"]}"' in section for e in listed), section[:2000]
    assert 'href="/components/builder/executions"' in section and "12.5 s" in section
    chosen = client.get("/components/builder/executions?host=perf-a")
    assert chosen.status_code == 200 and '<option value="perf-a" selected>' in chosen.text
    assert re.findall(r'href="/executions/(\d+)"', chosen.text) == [str(r2.id)]
    assert client.get("/components/builder/executions?state=closed").status_code == 400


def test_the_executions_page_pages_with_the_apis_cursor(
    client, database_url, tmp_path, monkeypatch
):
    history(database_url, tmp_path, [20.0, 20.0])
    monkeypatch.setattr(web, "EXECUTIONS_PAGE", 1)
    first = client.get("/components/builder/executions")
    following = re.search(r'id="next-page" href="\?([^"]+)"', first.text)
    assert following, "a full page links the next one"
    second = client.get("/components/builder/executions?" + html.unescape(following.group(1)))
    assert second.status_code == 200 and 'id="first-page"' in second.text
    shown = [re.findall(r'href="/executions/(\d+)"', p.text) for p in (first, second)]
    assert len(shown[0]) == len(shown[1]) == 1 and shown[0] != shown[1]


def test_the_trends_filter_by_host_kept_in_the_address(client, database_url, tmp_path):
    history(database_url, tmp_path, [20.0, 20.0, 20.0])
    _ran_on(database_url, "r2", "perf-a")
    _ran_on(database_url, "r3", "perf-b")
    page = client.get("/components/builder?host=perf-a&counter=cpu")
    assert page.status_code == 200
    assert [r[0] for r in trend_data(page.text)["revisions"]] == ["r2"]  # perf-a's alone
    assert '<option value="perf-a" selected>' in page.text and 'value="perf-b"' in page.text
    assert 'data-view="counter=cpu&amp;host=perf-a"' in page.text  # the address keeps it
    data = client.get("/components/builder/trends?host=perf-b").json()
    assert [r[0] for r in data["page"]["revisions"]] == ["r3"] and data["view"] == "host=perf-b"
    everyone = trend_data(client.get("/components/builder").text)["revisions"]
    assert [r[0] for r in everyone] == ["r1", "r2", "r3"]
    unknown = client.get("/components/builder?host=nope")
    assert unknown.status_code == 400 and "host: no performance host" in html.unescape(unknown.text)


def test_regressions_filter_by_method_and_come_a_page_at_a_time(
    client, database_url, tmp_path, monkeypatch
):
    history(database_url, tmp_path, [20.0, 20.0, 200.0, 200.0, 800.0])
    every = client.get(f"{API}/regressions").json()
    assert len(every) >= 2 and all("ks" in r["methods"] for r in every)
    assert client.get(f"{API}/regressions?method=ks").json() == every
    assert client.get(f"{API}/regressions?method=welch_t").json() == []
    numbers = [f'href="/regressions/{r["id"]}"' for r in every]
    page = client.get("/regressions?method=ks").text
    assert all(link in page for link in numbers) and '<option value="ks" selected>' in page
    # each method by what it is: a new user took "foo" (Foo et al.) for leftover test code
    assert '<option value="foo">Foo et al. 2010, association rules</option>' in page
    assert set(TITLES) == set(DETECTORS)
    assert "No regression matches." in client.get("/regressions?method=welch_t").text
    bad = client.get("/regressions?method=nonsense")
    assert bad.status_code == 400 and "method: one of" in html.unescape(bad.text)

    monkeypatch.setattr(regression_pages, "PAGE", 1)
    seen, address = [], "/regressions?method=ks"
    while address:
        page = client.get(address).text
        seen += re.findall(r'<a href="/regressions/(\d+)">#', page)
        following = re.search(r'id="next-page" href="\?([^"]+)"', page)
        address = f"/regressions?{html.unescape(following.group(1))}" if following else ""
        assert not following or "method=ks" in address  # the filters go with the cursor
    assert sorted(seen) == sorted(str(r["id"]) for r in every) and len(set(seen)) == len(seen)


def test_the_regressions_page_lists_those_that_stand_unless_asked_for_all(
    client, database_url, tmp_path
):
    """A new user found a noisy rss_bytes "regression", dropped by its re-runs, listed beside
    the real one: the page lists the confirmed and suspected ones unless asked for all."""
    history(database_url, tmp_path, [20.0, 20.0, 200.0, 200.0, 800.0])
    every = client.get(f"{API}/regressions").json()
    dropped, *standing = every
    with session_factory(database_url)() as session:
        session.execute(
            update(Regression)
            .where(Regression.id == dropped["id"])
            .values(confirmation="not_confirmed")
        )
        session.commit()
    link = f'href="/regressions/{dropped["id"]}"'
    page = client.get("/regressions").text
    assert link not in page and all(f'href="/regressions/{r["id"]}"' in page for r in standing)
    assert '<option value="standing" selected>confirmed or suspected</option>' in page
    assert link in client.get("/regressions?confirmation=all").text
    assert link in client.get("/regressions?confirmation=not_confirmed").text
    listed = client.get(f"{API}/regressions?confirmation=standing").json()
    assert [r["id"] for r in listed] == [r["id"] for r in standing]


def _disturbed(database_url: str, title: str, legs: int, why: str) -> None:
    """The revision's execution measured the phase at ``legs`` while the host was busy."""
    (execution,) = _executions_of(database_url, title)
    with session_factory(database_url)() as session:
        legs_at = canonical_params({"legs": legs})
        ids = session.scalars(select(Series.id).where(Series.params == legs_at))
        path = samples_path(execution.recording_path)
        table = pq.read_table(path)
        busy = json.dumps({str(i): why for i in ids}).encode()
        pq.write_table(table.replace_schema_metadata({DISTURBED: busy}), path)


def _row(page: str, label: str, method: str) -> list[str]:
    """The cells of the verdicts table's row of ``label`` by ``method``, as text."""
    for row in re.findall(r"<tr[^>]*>(.*?)</tr>", page, re.S):
        cells = [html.unescape(re.sub(r"<[^>]+>", "", c)).strip() for c in re.findall(
            r"<td[^>]*>(.*?)</td>", row, re.S)]  # fmt: skip
        if cells and cells[0] == label and method in cells:
            return cells
    raise AssertionError(f"no row of {label} by {method}")


def test_a_ks_rows_values_are_the_means_its_change_is_of(client, database_url, tmp_path):
    """A trial read a KS row of 9.919e+06 against 9.945e+06 beside a change of -0.6 %: the
    values were medians of the runs' medians, KS's change that of the pooled samples' mean.
    Here the median rises (10 to 11) while the mean falls (about 15 to 11)."""
    import numpy as np
    from redline.server.models import DetectionConfigRow
    from redline.server.schemas.components import ComponentCreate
    from redline.server.services.components import create_component

    from tests.support.history import add_executions, ingest_and_detect

    skewed = np.concatenate([np.full(50, 10.0), np.full(10, 40.0)])  # median 10, mean 15
    level = np.random.default_rng(3).normal(11.0, 0.05, 60)  # median and mean 11
    with session_factory(database_url)() as session:
        component = create_component(session, ComponentCreate(name="builder"))
        session.add(DetectionConfigRow(component_id=component.id, config={"methods": ["ks"]}))
        session.commit()
        executions = [
            *add_executions(session, tmp_path, "builder", "r1", "1", [{"cpu": skewed}]),
            *add_executions(session, tmp_path, "builder", "r2", "2", [{"cpu": level}]),
        ]
    ingest_and_detect(database_url, executions)
    page = client.get("/components/builder/revisions/r2").text
    cells = _row(page, "throughput/publish[rate=10] component.cpu", "ks")
    baseline, candidate = (float(cells[i]) for i in (2, 3))
    change = float(cells[cells.index("ks") + 2].removesuffix(" %")) / 100
    assert baseline == pytest.approx(15.0, rel=0.01) and candidate == pytest.approx(11, rel=0.01)
    assert change == pytest.approx((candidate - baseline) / baseline, abs=0.002), cells


def test_the_revision_page_shows_both_values_and_each_runs_duration_and_disturbance(
    client, database_url, tmp_path
):
    history(database_url, tmp_path, [20.0, 20.0, 200.0])
    _run_took(database_url, "r3", "42.250")
    _disturbed(database_url, "r3", 8, "host busy: 180 % of a core")
    page = client.get("/components/builder/revisions/r3").text
    assert "<th>baseline value</th>" in re.sub(r' title="[^"]*"', "", page)
    cells = _row(page, "build/steady[legs=2] builder.cpu", "ks")
    baseline, candidate = (float(cells[i]) for i in (2, 3))  # series, baseline, then the values
    assert 18 < baseline < 22 and 180 < candidate < 220, cells
    jobs = page[page.index('<table id="jobs">') : page.index("</table>")]
    assert "42.2 s" in jobs, jobs  # 42.25 s as %.1f
    assert "build/steady[legs=8]: host busy: 180 % of a core" in html.unescape(jobs), jobs
    assert "build/steady[legs=2]" not in html.unescape(jobs)
    plain = client.get("/components/builder/revisions/r2").text
    quiet = plain[plain.index('<table id="jobs">') : plain.index("</table>")]
    assert '<td class="disturbed">none</td>' in quiet and '<td class="duration">—</td>' in quiet


def test_the_revision_page_folds_the_series_without_a_verdict(client, database_url, tmp_path):
    """On a young history the "not enough data" rows outnumbered the verdicts (the demo's newest
    revision: 56 of 81 rows) and buried them; they are folded, each with its reason."""
    history(database_url, tmp_path, [20.0, 20.0, 200.0])
    first = client.get("/components/builder/revisions/r1").text
    assert 'id="detections"' not in first  # nothing judged: no baseline yet
    folded = first[first.index('<details id="waiting" open>') : first.index("</details>")]
    assert "series without a verdict yet (not enough data)" in folded
    assert folded.count('<tr><td class="label">') == 4 and "missing baseline" in folded
    judged = client.get("/components/builder/revisions/r3").text
    assert 'id="detections"' in judged and '<details id="waiting"' not in judged
    assert judged.count('<a href="/detections/') == 4  # each verdict's why


def test_the_revision_page_tells_a_change_for_the_better_from_one_for_the_worse(
    client, database_url, tmp_path
):
    """A trial's unchanged revision showed an improvement in the regressions' pink, as
    "change (decrease)"; and its confirmation column said "held" where the regression's page
    says "confirmed"."""
    history(database_url, tmp_path, [20.0, 20.0, 6.0, 60.0])
    better = client.get("/components/builder/revisions/r3").text
    cells = _row(better, "build/steady[legs=2] builder.cpu", "change (decrease, better)")
    assert cells, better
    assert '<tr class="improved">' in better and '<tr class="flagged">' not in better
    worse = client.get("/components/builder/revisions/r4").text
    assert '<tr class="flagged">' in worse and "change (increase, worse)" in worse
    assert ">held<" not in worse and ">dropped<" not in worse


def test_compare_shows_the_candidates_verdicts_and_pools_ranges(
    client, database_url, tmp_path, monkeypatch
):
    history(database_url, tmp_path, [20.0, 20.0, 200.0])
    one = client.get(f"{API}/compare?base=r2&candidate=r3").json()
    pooled = client.get(f"{API}/compare?base=r1..r2&candidate=r3").json()
    assert pooled["base_revisions"] == ["r1", "r2"] and pooled["candidate_revisions"] == ["r3"]
    assert pooled["series"][0]["baseline"]["n"] == 2 * one["series"][0]["baseline"]["n"]
    backwards = client.get(f"{API}/compare?base=r2..r1&candidate=r3").json()
    assert backwards["base_revisions"] == ["r1", "r2"]  # a range in sort-key order
    assert client.get(f"{API}/compare?base=r1..r9&candidate=r3").status_code == 404
    overlapping = client.get(f"{API}/compare?base=r1..r3&candidate=r3")  # a trial's
    assert overlapping.status_code == 400 and "share r3" in overlapping.text, overlapping.text

    page = client.get("/components/builder/compare?base=r1..r2&candidate=r3")
    assert page.status_code == 200 and "Baseline: r1, r2 · candidate: r3" in page.text
    assert "<th>ks verdict</th><th>ks score</th>" in page.text
    cells = _row(page.text, "build/steady[legs=2] builder.cpu", "change (increase)")
    assert cells[-1].startswith(("ks: suspected", "ks: confirmed")), cells
    detections = client.get(f"{API}/detections?revision=r3&method=ks").json()
    assert all(f'href="/detections/{d["id"]}"' in page.text for d in detections)
    chosen = client.get(
        "/components/builder/compare?base=r1&base_through=r2&candidate=r3&candidate_through=",
        follow_redirects=False,
    )
    assert chosen.status_code == 303 and chosen.headers["location"] == "?base=r1..r2&candidate=r3"
    monkeypatch.setattr(compare, "MAX_RANGE", 1)
    wide = client.get("/components/builder/compare?base=r1..r2&candidate=r3")
    assert wide.status_code == 400 and "spans more than 1 revisions" in html.unescape(wide.text)


def test_a_sign_in_posted_from_elsewhere_is_refused(client, database_url):
    """Login CSRF: another site's form signs a browser in to the other site's account, unless
    the sign-in form carries a token of the browser's own."""
    with session_factory(database_url)() as session:
        create_user(session, "mallory", PASSWORD, "ci")
    forged = client.post("/signin", data={"name": "mallory", "password": PASSWORD})
    assert forged.status_code == 403 and "token does not match" in html.unescape(forged.text)
    assert SESSION_COOKIE not in client.cookies
    client.get("/signin")  # the browser has its sign-in cookie, the forger not its value
    guessed = client.post(
        "/signin", data={"name": "mallory", "password": PASSWORD, "csrf": "x" * 43}
    )
    assert guessed.status_code == 403 and SESSION_COOKIE not in client.cookies
    signed = sign_in(client, {"name": "mallory", "password": PASSWORD}, follow_redirects=False)
    assert signed.status_code == 303 and SESSION_COOKIE in client.cookies
    cookie = client.get("/signin").headers["set-cookie"].lower()
    assert "httponly" in cookie and "samesite=strict" in cookie and "path=/signin" in cookie


def _analysed_now(database_url: str, title: str) -> None:
    with session_factory(database_url)() as session:
        session.execute(
            update(Revision).where(Revision.title == title).values(analyzed_at=utcnow())
        )
        session.commit()


def _cached_versions(database_url: str) -> dict[str, str]:
    with session_factory(database_url)() as session:
        return dict(session.execute(select(FigureCache.view, FigureCache.version)).all())


def test_a_views_data_version_is_read_from_its_own_revisions(client, database_url, tmp_path):
    """The cache's version was the newest execution and analysis of the whole history, read on
    every request: a page's cost grew with it. A view's is its revisions' (and the one before)."""
    history(database_url, tmp_path, [20.0, 20.0, 20.0])
    client.get("/components/builder?revisions=1")  # r3, and r2 to know there is earlier history
    (first,) = _cached_versions(database_url).values()
    _analysed_now(database_url, "r1")  # outside the view: its page stays as it was
    client.get("/components/builder?revisions=1")
    assert _cached_versions(database_url) == {"revisions=1": first}
    _analysed_now(database_url, "r3")  # analysed again: its marks may have changed
    client.get("/components/builder?revisions=1")
    assert _cached_versions(database_url)["revisions=1"] != first
